"""Numba kernels for a winding driven by a voltage known between samples by its moments.

The zero-order-hold model of :mod:`observer.estimation.kernels` assumes the
voltage is constant over each sample period. A converter's voltage is not: a
thyristor bridge applies mains sine segments with a jump at every firing, and
the measured samples pass anti-aliasing filters first. Here the voltage over
interval ``k`` (from sample ``k`` to ``k+1``) is described by its first three
Legendre moments::

    mu_j[k] = int_0^1 v(t_k + u*T) * P_j(u) du,   P_0 = 1, P_1 = 2u - 1, P_2 = 6u^2 - 6u + 1

and the winding ``v = R*i + L*di/dt`` is discretised exactly for any voltage
whose weight ``exp(-x*(1-u))`` (``x = R*T/L``) is well represented by a
quadratic over one period (error ~ x^3/2000; x < 0.3 in practice)::

    i[k+1] = a*i[k] + c_0*mu_0[k] + c_1*mu_1[k] + c_2*mu_2[k]
    a = exp(-x),   c_j = (x/R)*(2j+1)*int_0^1 exp(-x*(1-u)) P_j(u) du

A held voltage has ``mu_1 = mu_2 = 0`` and ``c_0 = (1-a)/R``: the ZOH model.

Segments
--------
Where the voltage between two samples is not known (a switching instant falls
inside the interval and the samples do not say when), the simulation restarts:
the window is a list of segments, sample ranges ``[start, end]`` whose
intervals are all known, each with its own initial current solved in closed
form. The EMF constant ``K`` is shared by all segments and also solved in
closed form (variable projection over ``K`` and every segment's ``i0``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction
from typing import cast

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic

from observer.estimation.kernels import geometric_energy

#: Below this, the closed-form weights lose digits to cancellation: use the series,
#: whose terms fall as x^n/n! (16 terms: below 1e-16 relative for x < 1).
_SERIES_X = 1.0
_SERIES_TERMS = 16


def _series(weight: Callable[[int], Fraction]) -> np.ndarray:
    """The series' coefficients ``(-1)^n/n! * weight(n)``, exact until rounded to double."""
    return np.array(
        [float(Fraction((-1) ** n, math.factorial(n)) * weight(n)) for n in range(_SERIES_TERMS)]
    )


#: w_j = sum_n (-x)^n/n! * int_0^1 s^n P_j(1 - s) ds (s = 1 - u), whose integrals
#: are 1/(n+1), -n/((n+1)(n+2)) and n(n-1)/((n+1)(n+2)(n+3)): polynomials in x,
#: evaluated by Horner's rule (no divisions: half the time of summing the terms).
_W0 = _series(lambda n: Fraction(1, n + 1))
_W1 = _series(lambda n: Fraction(-n, (n + 1) * (n + 2)))
_W2 = _series(lambda n: Fraction(n * (n - 1), (n + 1) * (n + 2) * (n + 3)))

#: Free responses are floored (see :data:`observer.estimation.kernels._G_FLOOR`).
_G_FLOOR = 1e-200
_A_FLOOR = 1e-100

#: Below this Gram determinant (relative), K is not identifiable from the window.
_SINGULAR_RTOL = 1e-10

EMF_NONE = 0
"""No EMF term (the field winding)."""
EMF_FIT = 1
"""Fit ``K`` by projection."""
EMF_HELD = 2
"""Hold ``K`` at a given value."""


@njit(nogil=True, cache=True, fastmath={"contract"})
def _horner3(
    p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, x: float
) -> tuple[float, float, float]:
    """Three polynomials of the same degree (coefficients from the constant up) at ``x``,
    by Horner's rule, without divisions."""
    last = p0.shape[0] - 1
    v0 = p0[last]
    v1 = p1[last]
    v2 = p2[last]
    for n in range(last - 1, -1, -1):
        v0 = v0 * x + p0[n]
        v1 = v1 * x + p1[n]
        v2 = v2 * x + p2[n]
    return v0, v1, v2


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_coefficients(
    resistance: float, inductance: float, dt: float
) -> tuple[float, float, float, float]:
    """``(a, c_0, c_1, c_2)`` of the exact update for period ``dt`` (see the module notes)."""
    x = resistance * dt / inductance
    if x < _SERIES_X:
        w0, w1, w2 = _horner3(_W0, _W1, _W2, x)
        a = math.exp(-x)
    else:
        om = -math.expm1(-x)
        a = 1.0 - om
        y = 1.0 / x
        m0 = om * y  # int w
        m1 = (1.0 - om * y) * y  # int w u
        m2 = (1.0 - 2.0 * y + 2.0 * y * y * om) * y  # int w u^2
        w0 = m0
        w1 = 2.0 * m1 - m0
        w2 = 6.0 * m2 - 6.0 * m1 + m0
    g = x / resistance
    return a, g * w0, 3.0 * g * w1, 5.0 * g * w2


#: The series' derivatives: ``w_j'(x) = sum_n (n+1) * W_j[n+1] * x^n``.
_W0_SLOPE = _W0[1:] * np.arange(1, _SERIES_TERMS)
_W1_SLOPE = _W1[1:] * np.arange(1, _SERIES_TERMS)
_W2_SLOPE = _W2[1:] * np.arange(1, _SERIES_TERMS)


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_coefficient_slopes(
    resistance: float, inductance: float, dt: float
) -> tuple[float, float, float, float]:
    """``(da, dc_0, dc_1, dc_2)``: the derivatives of :func:`moment_coefficients` by ``ln R``.

    With ``x = R*T/L`` and ``beta = T/L``, ``a`` depends on ``x`` alone and
    ``c_j = beta * (2j+1) * w_j(x)``, so ``d/d ln R = x d/dx`` and
    ``d/d ln L = -x d/dx - beta d/d beta``: ``da/d ln L = -da/d ln R`` and
    ``dc_j/d ln L = -dc_j/d ln R - c_j``.
    """
    x = resistance * dt / inductance
    if x < _SERIES_X:
        d0, d1, d2 = _horner3(_W0_SLOPE, _W1_SLOPE, _W2_SLOPE, x)
        a = math.exp(-x)
    else:
        # The closed forms of moment_coefficients, differentiated (d om/dx = a, dy/dx = -y^2).
        om = -math.expm1(-x)
        a = 1.0 - om
        y = 1.0 / x
        m0 = om * y
        dm0 = y * (a - m0)
        dm1 = y * y * (2.0 * om * y - 1.0 - a)
        dm2 = y * y * (4.0 * y + 2.0 * a * y - 6.0 * om * y * y - 1.0)
        d0 = dm0
        d1 = 2.0 * dm1 - dm0
        d2 = 6.0 * dm2 - 6.0 * dm1 + dm0
    gx = dt / inductance * x
    return -x * a, gx * d0, 3.0 * gx * d1, 5.0 * gx * d2


@njit(nogil=True, cache=True)
def segment_noise_energy(a: float, c0: float, m: int) -> float:
    """Expected sum of squares over a segment of ``m`` samples of unit white input noise.

    Noise on the voltage reaches the simulated current through ``h_j = c_0*a^j``
    (the zeroth moment of white noise is the noise itself); see
    :func:`observer.estimation.kernels.input_noise_energy`.
    """
    aa = a * a
    if aa >= 1.0:
        return c0 * c0 * m * (m - 1) / 2.0
    return c0 * c0 / (1.0 - aa) * (m - geometric_energy(a, m))


@njit(nogil=True, cache=True, fastmath={"contract"})
def plain_moment_swarm_costs(
    positions: np.ndarray,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    log_scale: bool,
    emf_mode: int,
    emf_constant: float,
    input_noise_var: float,
) -> np.ndarray:
    """The reference form of :func:`moment_swarm_costs`: the same cost, written plainly.

    The loops run as the equations read (samples outside, particles inside,
    every state in memory); the fast kernel must agree with it to rounding
    (``tests/observer/estimation/test_intersample_kernels.py``) and the
    benchmark measures both (``python -m bench.kernel_speed``).

    Parameters
    ----------
    positions : (n_particles, 2) array
        ``(R [ohm], L [H])`` per particle, or their base-10 logarithms.
    mu, mu_emf : (n - 1, 3) arrays
        Legendre moments of the winding voltage (V) and of ``if*omega``
        (A*rad/s) over each interval; ``mu_emf`` is ignored when
        ``emf_mode == EMF_NONE``.
    current : (n,) array
        Measured winding current (A).
    starts, ends : (n_segments,) int arrays
        First and last sample of each segment (inclusive; intervals between
        segments are skipped).
    emf_mode : {EMF_NONE, EMF_FIT, EMF_HELD}
    emf_constant : float
        ``K`` when ``emf_mode == EMF_HELD``.
    input_noise_var : float
        Variance (V^2) of white noise on the voltage whose expected share of
        the cost is subtracted (errors-in-variables compensation).

    Returns
    -------
    (n_particles,) array of sums of squared current error (A^2).
    """
    n_particles = positions.shape[0]
    a = np.empty(n_particles)
    a_g = np.empty(n_particles)
    c0 = np.empty(n_particles)
    c1 = np.empty(n_particles)
    c2 = np.empty(n_particles)
    for p in range(n_particles):
        r = positions[p, 0]
        ell = positions[p, 1]
        if log_scale:
            r = 10.0**r
            ell = 10.0**ell
        a[p], c0[p], c1[p], c2[p] = moment_coefficients(r, ell, dt)
        a_g[p] = max(a[p], _A_FLOOR)
    has_emf = emf_mode != EMF_NONE
    k_held = emf_constant if emf_mode == EMF_HELD else 0.0
    fit_k = emf_mode == EMF_FIT
    big_a = np.zeros(n_particles)
    big_b = np.zeros(n_particles)
    big_c = np.zeros(n_particles)
    noise = np.zeros(n_particles)
    f = np.empty(n_particles)
    fe = np.empty(n_particles)
    g = np.empty(n_particles)
    s_dd = np.empty(n_particles)
    s_dg = np.empty(n_particles)
    s_de = np.empty(n_particles)
    s_ee = np.empty(n_particles)
    s_eg = np.empty(n_particles)
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        for p in range(n_particles):
            f[p] = 0.0
            fe[p] = 0.0
            g[p] = 1.0
            s_dd[p] = 0.0
            s_dg[p] = 0.0
            s_de[p] = 0.0
            s_ee[p] = 0.0
            s_eg[p] = 0.0
        for k in range(st, en + 1):
            y = current[k]
            last = k == en
            if last:
                m0 = 0.0
                m1 = 0.0
                m2 = 0.0
                e0 = 0.0
                e1 = 0.0
                e2 = 0.0
            else:
                m0 = mu[k, 0]
                m1 = mu[k, 1]
                m2 = mu[k, 2]
                if has_emf:
                    e0 = mu_emf[k, 0]
                    e1 = mu_emf[k, 1]
                    e2 = mu_emf[k, 2]
                    if not fit_k:
                        m0 -= k_held * e0
                        m1 -= k_held * e1
                        m2 -= k_held * e2
                else:
                    e0 = 0.0
                    e1 = 0.0
                    e2 = 0.0
            if fit_k:
                for p in range(n_particles):
                    d = y - f[p]
                    gp = g[p]
                    fep = fe[p]
                    s_dd[p] += d * d
                    s_dg[p] += d * gp
                    s_de[p] += d * fep
                    s_ee[p] += fep * fep
                    s_eg[p] += fep * gp
                    ap = a[p]
                    f[p] = ap * f[p] + c0[p] * m0 + c1[p] * m1 + c2[p] * m2
                    fe[p] = ap * fep + c0[p] * e0 + c1[p] * e1 + c2[p] * e2
                    g[p] = a_g[p] * gp + _G_FLOOR
            else:
                for p in range(n_particles):
                    d = y - f[p]
                    gp = g[p]
                    s_dd[p] += d * d
                    s_dg[p] += d * gp
                    f[p] = a[p] * f[p] + c0[p] * m0 + c1[p] * m1 + c2[p] * m2
                    g[p] = a_g[p] * gp + _G_FLOOR
        m_seg = en - st + 1
        for p in range(n_particles):
            s_gg = geometric_energy(a[p], m_seg)
            big_a[p] += s_dd[p] - s_dg[p] * s_dg[p] / s_gg
            if fit_k:
                big_b[p] += s_de[p] - s_dg[p] * s_eg[p] / s_gg
                big_c[p] += s_ee[p] - s_eg[p] * s_eg[p] / s_gg
            if input_noise_var > 0.0:
                noise[p] += segment_noise_energy(a[p], c0[p], m_seg)
    out = np.empty(n_particles)
    for p in range(n_particles):
        cost = big_a[p]
        if fit_k and big_c[p] > _SINGULAR_RTOL * abs(big_a[p]) + 1e-300:
            cost -= big_b[p] * big_b[p] / big_c[p]
        out[p] = cost - input_noise_var * noise[p]
    return out


# ---------------------------------------------------------------- the fast swarm cost

#: Bytes of one SIMD register the fast kernel fills (AVX2: four doubles, eight floats).
VECTOR_BYTES = 32

#: Doubles per vector. The swarm is padded to whole blocks of :data:`BLOCK_VECTORS`
#: vectors (the padding repeats the last particle).
LANES = VECTOR_BYTES // 8

#: Rows of the particle-major work array of :func:`moment_swarm_costs`: the
#: states and sums one particle carries along a segment, then its constants.
#: ``h = f/c_0`` and ``h_e = f_e/c_0`` are the forced responses scaled so that a
#: held input enters without a product; ``r_j = c_j/c_0``.
_H, _HE, _G, _SDD, _SDG, _SDE, _SEE, _SEG, _A, _C0, _AG, _R1, _R2 = range(13)
_ROWS = 13

#: FMAs per particle and sample of the inner loops: (fit K?, moments) -> count.
#: Field or K held: d, s_dd, s_dg, h, g (+2 for the moments' input); K fitted:
#: also h_e, s_de, s_ee, s_eg (+2 more for its moments).
FMAS_PER_PARTICLE_SAMPLE = {(False, 1): 5, (False, 3): 7, (True, 1): 9, (True, 3): 13}

#: Vectors of particles one block carries through the samples: (fit K?) -> count.
#: Each state is a chain of one FMA (4 cycles) per sample, so a block needs at
#: least 8 FMAs per sample to keep both FMA pipes busy, and its states and
#: constants must fit the 16 vector registers. With ``K`` fitted one vector does
#: (9 or 13 FMAs, 13 registers); two spill and ran at half the speed. Without,
#: two vectors (10 or 14 FMAs): one ran ~30 % slower (latency), three spilled.
_FIT_VECTORS = 1
_PLAIN_VECTORS = 2
BLOCK_VECTORS = {False: _PLAIN_VECTORS, True: _FIT_VECTORS}

#: Samples per tile: every block of the swarm runs through a tile before the next,
#: so the tile's inputs (56 bytes a sample) stay in the core's cache.
_TILE = 2048


def _swarm_block(fit: bool, moments: int, n_vec: int) -> Callable[..., None]:
    """A numba intrinsic running ``n_vec`` vectors of particles through samples ``k0 .. k1-1``.

    The returned ``block(w, y, mu, mu_emf, j, k0, k1)`` loads the states and
    constants of the particles ``j ..`` (``n_vec`` whole vectors) from the
    work array ``w`` (:data:`_ROWS` rows, particle-major), keeps the states in
    vector registers while it takes the intervals ``k0 .. k1-1`` one after
    another (each: the sums of the sample, then the update by its input), and
    stores them back. Written as LLVM vector IR because it is a blocking the
    loop vectoriser does not produce (it vectorises the innermost loop, the
    particles; here the samples run inside the particle block). The element
    type is the arrays' (float64: :data:`LANES` lanes, float32: twice as many),
    all C-contiguous; ``mu`` holds ``(p, q, z)`` per interval (with ``K`` held,
    less ``K`` times the EMF's), ``mu_emf`` the EMF's (read when ``fit``).
    """
    state_rows = [_H, _G, _SDD, _SDG] + ([_HE, _SDE, _SEE, _SEG] if fit else [])

    def typer(typingctx, w, y, mu, mu_emf, j, k0, k1):
        for name, ty, nd in (("w", w, 2), ("y", y, 1), ("mu", mu, 2), ("mu_emf", mu_emf, 2)):
            if not (isinstance(ty, types.Array) and ty.layout == "C" and ty.ndim == nd):
                raise TypingError(f"swarm block: {name} must be a C-contiguous {nd}-d array")
            if ty.dtype != w.dtype or ty.dtype not in (types.float64, types.float32):
                raise TypingError("swarm block: arrays must all be float64 or all float32")
        sig = types.void(w, y, mu, mu_emf, types.intp, types.intp, types.intp)
        return sig, codegen

    def codegen(context, builder, signature, args):
        w_ty, y_ty, mu_ty, emf_ty = signature.args[:4]
        fty = context.get_value_type(w_ty.dtype)
        size = context.get_abi_sizeof(fty)
        lanes = VECTOR_BYTES // size
        vty = ir.VectorType(fty, lanes)
        intp = context.get_value_type(types.intp)
        i32 = ir.IntType(32)
        w, y, mu, mu_emf = (
            context.make_array(t)(context, builder, a)
            for t, a in zip((w_ty, y_ty, mu_ty, emf_ty), args[:4], strict=True)
        )
        j, k0, k1 = args[4:]
        width = cgutils.unpack_tuple(builder, w.shape, 2)[1]
        undef = ir.Constant(vty, ir.Undefined)
        splat = ir.Constant(ir.VectorType(i32, lanes), [0] * lanes)

        def fma(x, m, c):
            # x*m + c, contractible as the rest of the kernels: one FMA where the
            # core has them (llvm.fma would call libm per lane where it has not).
            return builder.fadd(builder.fmul(x, m, flags=("contract",)), c, flags=("contract",))

        def row(r: int, v: int):
            col = builder.add(j, ir.Constant(intp, v * lanes))
            idx = builder.add(builder.mul(ir.Constant(intp, r), width), col)
            return builder.bitcast(builder.gep(w.data, [idx]), vty.as_pointer())

        def broadcast(arr, idx):
            x = builder.load(builder.gep(arr.data, [idx]))
            return builder.shuffle_vector(
                builder.insert_element(undef, x, ir.Constant(i32, 0)), undef, splat
            )

        init = [{r: builder.load(row(r, v), align=size) for r in state_rows} for v in range(n_vec)]
        const = []
        for v in range(n_vec):
            c = {r: builder.load(row(r, v), align=size) for r in (_A, _C0, _AG, _R1, _R2)}
            c[_C0] = builder.fneg(c[_C0])  # d = y - c0*h as one FMA
            const.append(c)
        floor = ir.Constant(vty, [ir.Constant(fty, _G_FLOOR)] * lanes)
        entry = builder.basic_block
        header = builder.append_basic_block("block.header")
        body = builder.append_basic_block("block.body")
        done = builder.append_basic_block("block.done")
        builder.branch(header)
        builder.position_at_end(header)
        k = builder.phi(intp)
        k.add_incoming(k0, entry)
        state = []
        for v in range(n_vec):
            phis = {}
            for r in state_rows:
                phis[r] = builder.phi(vty)
                phis[r].add_incoming(init[v][r], entry)
            state.append(phis)
        builder.cbranch(builder.icmp_signed("<", k, k1), body, done)
        builder.position_at_end(body)
        yk = broadcast(y, k)
        k3 = builder.mul(k, ir.Constant(intp, 3))
        inputs = []
        for arr in (mu, mu_emf) if fit else (mu,):
            inputs.append(
                [broadcast(arr, builder.add(k3, ir.Constant(intp, m))) for m in range(moments)]
            )
        updated = []
        for v in range(n_vec):
            s, c = state[v], const[v]
            h, g = s[_H], s[_G]
            d = fma(c[_C0], h, yk)
            new = {_SDD: fma(d, d, s[_SDD]), _SDG: fma(d, g, s[_SDG])}
            forced = [(_H, h, inputs[0])]
            if fit:
                he = s[_HE]
                new[_SDE] = fma(d, he, s[_SDE])
                new[_SEE] = fma(he, he, s[_SEE])
                new[_SEG] = fma(he, g, s[_SEG])
                forced.append((_HE, he, inputs[1]))
            for r, x, u in forced:
                drive = u[0] if moments == 1 else fma(c[_R2], u[2], fma(c[_R1], u[1], u[0]))
                new[r] = fma(c[_A], x, drive)
            new[_G] = fma(c[_AG], g, floor)
            updated.append(new)
        latch = builder.basic_block
        k.add_incoming(builder.add(k, ir.Constant(intp, 1)), latch)
        for v in range(n_vec):
            for r in state_rows:
                state[v][r].add_incoming(updated[v][r], latch)
        back = builder.branch(header)
        # One sample per pass, as written (LLVM unrolled it 3-5x, no faster when measured):
        # what `bench.kernel_speed`'s assembly check counts.
        loop_id = builder.module.add_metadata([])
        loop_id.operands = (
            loop_id,
            builder.module.add_metadata(
                [ir.MetaDataString(builder.module, "llvm.loop.unroll.disable")]
            ),
        )
        back.set_metadata("llvm.loop", loop_id)
        builder.position_at_end(done)
        for v in range(n_vec):
            for r in state_rows:
                builder.store(state[v][r], row(r, v), align=size)
        return context.get_dummy_value()

    return cast("Callable[..., None]", intrinsic(typer))


_fit_hold_block = _swarm_block(True, 1, BLOCK_VECTORS[True])
_fit_moments_block = _swarm_block(True, 3, BLOCK_VECTORS[True])
_plain_hold_block = _swarm_block(False, 1, BLOCK_VECTORS[False])
_plain_moments_block = _swarm_block(False, 3, BLOCK_VECTORS[False])


@njit(nogil=True, cache=True)
def _block_width(x: np.ndarray, fit: bool) -> int:
    """Particles (lanes) of one block, in ``x``'s element type."""
    return (VECTOR_BYTES // x.itemsize) * (_FIT_VECTORS if fit else _PLAIN_VECTORS)


@njit(nogil=True, cache=True)
def _run_blocks(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, st: int, en: int,
    fit: bool, moments: int,
) -> None:  # fmt: skip
    """The intervals ``st .. en-1`` of a segment, tile by tile, every block of ``w`` in each."""
    step = _block_width(y, fit)
    for k0 in range(st, en, _TILE):
        k1 = min(k0 + _TILE, en)
        for j in range(0, w.shape[1], step):
            if fit:
                if moments == 1:
                    _fit_hold_block(w, y, mu, mu_emf, j, k0, k1)
                else:
                    _fit_moments_block(w, y, mu, mu_emf, j, k0, k1)
            elif moments == 1:
                _plain_hold_block(w, y, mu, mu_emf, j, k0, k1)
            else:
                _plain_moments_block(w, y, mu, mu_emf, j, k0, k1)


@njit(nogil=True, cache=True, fastmath={"contract"})
def _last_sample(w: np.ndarray, yk: float, fit: bool) -> None:
    """The sums of a segment's last sample (no interval follows it)."""
    for j in range(w.shape[1]):
        g = w[_G, j]
        d = yk - w[_C0, j] * w[_H, j]
        w[_SDD, j] += d * d
        w[_SDG, j] += d * g
        if fit:
            he = w[_HE, j]
            w[_SDE, j] += d * he
            w[_SEE, j] += he * he
            w[_SEG, j] += he * g


@njit(nogil=True, cache=True, fastmath={"contract"})
def _held_input(mu: np.ndarray, mu_emf: np.ndarray, k_held: float) -> np.ndarray:
    """The moments of ``v - K*if*omega`` with ``K`` held (once per call, not per particle)."""
    out = np.empty(mu.shape, mu.dtype)
    for k in range(mu.shape[0]):
        for m in range(3):
            out[k, m] = mu[k, m] - k_held * mu_emf[k, m]
    return out


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_swarm_costs(
    positions: np.ndarray,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    log_scale: bool,
    emf_mode: int,
    emf_constant: float,
    input_noise_var: float,
    n_moments: int = 3,
) -> np.ndarray:
    """Eq. (1) for every particle, over segments, ``K`` and each segment's ``i0`` projected out.

    Parameters
    ----------
    positions : (n_particles, 2) array
        ``(R [ohm], L [H])`` per particle, or their base-10 logarithms.
    mu, mu_emf : (n - 1, 3) arrays
        Legendre moments of the winding voltage (V) and of ``if*omega``
        (A*rad/s) over each interval; ``mu_emf`` is ignored when
        ``emf_mode == EMF_NONE``.
    current : (n,) array
        Measured winding current (A). Its dtype sets the arithmetic of the
        samples' loop: float64, or float32 (``mu`` and ``mu_emf`` then float32
        too; the coefficients and the projections stay float64). float32 runs
        twice the lanes but is not used: the sums before ``i0`` and ``K`` are
        projected out are 4e4 to 2e5 times the fit's residual, which float32's
        rounding over a window's sums does not keep (``python -m
        bench.kernel_speed`` measures the estimate it shifts: 15-70 times the
        spread the sensor noise gives).
    starts, ends : (n_segments,) int arrays
        First and last sample of each segment (inclusive; intervals between
        segments are skipped).
    emf_mode : {EMF_NONE, EMF_FIT, EMF_HELD}
    emf_constant : float
        ``K`` when ``emf_mode == EMF_HELD``.
    input_noise_var : float
        Variance (V^2) of white noise on the voltage whose expected share of
        the cost is subtracted (errors-in-variables compensation).
    n_moments : {3, 1}
        1: the voltage is held over each interval (only ``mu[:, 0]`` and
        ``mu_emf[:, 0]`` are read; the others must be 0), which saves two or
        four FMAs per particle and sample.

    Returns
    -------
    (n_particles,) array of sums of squared current error (A^2).

    Notes
    -----
    The same cost as :func:`plain_moment_swarm_costs`, to rounding. The swarm
    is laid out particle-major in one work array, padded to whole blocks of
    :data:`BLOCK_VECTORS` vectors, and each block runs through a tile of
    samples with its states in registers (:func:`_swarm_block`), so a sample
    costs its FMAs and the broadcast of its inputs, not loads and stores of
    the states. The forced responses are kept divided by ``c_0``, which saves
    a product per sample; a held ``K``'s EMF is subtracted from the input once
    per call. ``python -m bench.kernel_speed`` measures it against the FMA peak.
    """
    n_particles = positions.shape[0]
    fit_k = emf_mode == EMF_FIT
    held = emf_mode == EMF_HELD
    y = np.ascontiguousarray(current)
    u = np.ascontiguousarray(mu)
    e = np.ascontiguousarray(mu_emf)
    if held:
        u = _held_input(u, e, emf_constant)
    step = _block_width(y, fit_k)
    width = ((n_particles + step - 1) // step) * step
    w = np.empty((_ROWS, width), y.dtype)
    for j in range(width):
        p = min(j, n_particles - 1)
        r = positions[p, 0]
        ell = positions[p, 1]
        if log_scale:
            r = 10.0**r
            ell = 10.0**ell
        a, c0, c1, c2 = moment_coefficients(r, ell, dt)
        w[_A, j] = a
        w[_C0, j] = c0
        w[_AG, j] = max(a, _A_FLOOR)
        w[_R1, j] = c1 / c0
        w[_R2, j] = c2 / c0
    big_a = np.zeros(width)
    big_b = np.zeros(width)
    big_c = np.zeros(width)
    noise = np.zeros(width)
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        for j in range(width):
            w[_H, j] = 0.0
            w[_HE, j] = 0.0
            w[_G, j] = 1.0
            w[_SDD, j] = 0.0
            w[_SDG, j] = 0.0
            w[_SDE, j] = 0.0
            w[_SEE, j] = 0.0
            w[_SEG, j] = 0.0
        _run_blocks(w, y, u, e, st, en, fit_k, n_moments)
        _last_sample(w, y[en], fit_k)
        m_seg = en - st + 1
        for j in range(width):
            a = float(w[_A, j])
            c0 = float(w[_C0, j])
            s_gg = geometric_energy(a, m_seg)
            s_dg = float(w[_SDG, j])
            big_a[j] += w[_SDD, j] - s_dg * s_dg / s_gg
            if fit_k:
                s_eg = c0 * w[_SEG, j]
                big_b[j] += c0 * w[_SDE, j] - s_dg * s_eg / s_gg
                big_c[j] += c0 * c0 * w[_SEE, j] - s_eg * s_eg / s_gg
            if input_noise_var > 0.0:
                noise[j] += segment_noise_energy(a, c0, m_seg)
    out = np.empty(n_particles)
    for p in range(n_particles):
        cost = big_a[p]
        if fit_k and big_c[p] > _SINGULAR_RTOL * abs(big_a[p]) + 1e-300:
            cost -= big_b[p] * big_b[p] / big_c[p]
        out[p] = cost - input_noise_var * noise[p]
    return out


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_residual(
    resistance: float,
    inductance: float,
    emf_constant: float,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    has_emf: bool,
    out: np.ndarray,
    initial: np.ndarray,
) -> None:
    """Current residual (A) of every segment's sample, each segment's ``i0`` projected out.

    ``out`` receives the residuals of the segments' samples one after another
    (its length is the number of samples in segments); ``initial`` receives
    each segment's fitted initial current (A).

    The recursion is latency-bound: the interval's input is summed apart, so
    one FMA (not four dependent operations) separates ``f[k+1]`` from ``f[k]``,
    and the free response is kept from the first pass for the second.
    """
    a, c0, c1, c2 = moment_coefficients(resistance, inductance, dt)
    a_g = max(a, _A_FLOOR)
    longest = 0
    for s in range(starts.shape[0]):
        longest = max(longest, ends[s] - starts[s] + 1)
    free = np.empty(longest)
    pos = 0
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        f = 0.0
        g = 1.0
        s_dg = 0.0
        s_gg = 0.0
        for k in range(st, en):
            d = current[k] - f
            out[pos + k - st] = d
            free[k - st] = g
            s_dg += d * g
            s_gg += g * g
            if has_emf:
                u = (
                    c0 * (mu[k, 0] - emf_constant * mu_emf[k, 0])
                    + c1 * (mu[k, 1] - emf_constant * mu_emf[k, 1])
                    + c2 * (mu[k, 2] - emf_constant * mu_emf[k, 2])
                )
            else:
                u = c0 * mu[k, 0] + c1 * mu[k, 1] + c2 * mu[k, 2]
            f = a * f + u
            g = a_g * g + _G_FLOOR
        d = current[en] - f
        out[pos + en - st] = d
        free[en - st] = g
        s_dg += d * g
        s_gg += g * g
        i0 = s_dg / s_gg
        initial[s] = i0
        m = en - st + 1
        for i in range(m):
            out[pos + i] -= i0 * free[i]
        pos += m


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_residual_jacobian(
    resistance: float,
    inductance: float,
    emf_constant: float,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    emf_mode: int,
    out: np.ndarray,
    jac: np.ndarray,
    initial: np.ndarray,
    normal: np.ndarray,
) -> None:
    """:func:`moment_residual` and its derivatives by ``ln R``, ``ln L`` (and ``K``), one pass.

    ``out`` and ``initial`` receive what :func:`moment_residual` gives them (the
    same recursion, so the same numbers to rounding); ``jac`` (``(covered, 2)``, or
    ``(covered, 3)`` with ``emf_mode == EMF_FIT``) the derivatives of ``out``
    by ``ln R``, ``ln L`` and ``K``, each segment's ``i0`` projected out as
    in the residual (``r = d - i0*g``, ``i0 = (g.d)/(g.g)``, so
    ``dr = dd - di0*g - i0*dg``); ``normal`` (``(p, p + 1)``) ``J'J`` and
    ``J'r`` beside it, which the polish needs every step (over a tall ``J``
    of a few columns BLAS takes longer than this whole kernel).

    Only the sensitivity to ``ln R`` needs its own recursion: the forced
    response ``f`` is ``T/L`` times a function of ``x = R*T/L`` and the free
    response ``g`` a function of ``x`` alone, so ``df/d ln L = -df/d ln R - f``
    and ``dg/d ln L = -dg/d ln R``; ``df/dK`` is minus the response to
    ``if*omega``.
    """
    a, c0, c1, c2 = moment_coefficients(resistance, inductance, dt)
    da, q0, q1, q2 = moment_coefficient_slopes(resistance, inductance, dt)
    a_g = max(a, _A_FLOOR)
    da_g = da if a > _A_FLOOR else 0.0
    has_emf = emf_mode != EMF_NONE
    fit_k = emf_mode == EMF_FIT
    longest = 0
    for s in range(starts.shape[0]):
        longest = max(longest, ends[s] - starts[s] + 1)
    free = np.empty(longest)
    free_r = np.empty(longest)
    sums = np.zeros(9)
    pos = 0
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        f = 0.0
        f_r = 0.0
        f_e = 0.0
        g = 1.0
        g_r = 0.0
        s_dg = 0.0
        s_gg = 0.0
        s_fg = 0.0
        s_rg = 0.0  # d(g.d)/d ln R
        s_ggr = 0.0  # g.dg/d ln R
        s_eg = 0.0
        for k in range(st, en + 1):
            i = pos + k - st
            d = current[k] - f
            out[i] = d
            free[k - st] = g
            free_r[k - st] = g_r
            jac[i, 0] = f_r
            jac[i, 1] = f
            s_dg += d * g
            s_gg += g * g
            s_fg += f * g
            s_rg += d * g_r - f_r * g
            s_ggr += g * g_r
            if fit_k:
                jac[i, 2] = f_e
                s_eg += f_e * g
            if k == en:
                break
            m0 = mu[k, 0]
            m1 = mu[k, 1]
            m2 = mu[k, 2]
            if has_emf:
                e0 = mu_emf[k, 0]
                e1 = mu_emf[k, 1]
                e2 = mu_emf[k, 2]
                v0 = m0 - emf_constant * e0
                v1 = m1 - emf_constant * e1
                v2 = m2 - emf_constant * e2
                if fit_k:
                    f_e = a * f_e + (c0 * e0 + c1 * e1 + c2 * e2)
            else:
                v0 = m0
                v1 = m1
                v2 = m2
            u = c0 * v0 + c1 * v1 + c2 * v2
            f_r = a * f_r + (da * f + (q0 * v0 + q1 * v1 + q2 * v2))
            f = a * f + u
            g_r = a_g * g_r + da_g * g
            g = a_g * g + _G_FLOOR
        i0 = s_dg / s_gg
        initial[s] = i0
        di0_r = (s_rg - 2.0 * i0 * s_ggr) / s_gg
        di0_l = s_fg / s_gg - di0_r
        di0_k = s_eg / s_gg
        m = en - st + 1
        _project_segment(out, jac, free, free_r, pos, m, i0, (di0_r, di0_l, di0_k), fit_k, sums)
        pos += m
    normal[0, 0] = sums[0]
    normal[0, 1] = normal[1, 0] = sums[1]
    normal[1, 1] = sums[2]
    normal[0, -1] = sums[3]
    normal[1, -1] = sums[4]
    if fit_k:
        normal[0, 2] = normal[2, 0] = sums[5]
        normal[1, 2] = normal[2, 1] = sums[6]
        normal[2, 2] = sums[7]
        normal[2, -1] = sums[8]


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def _project_segment(
    out: np.ndarray,
    jac: np.ndarray,
    free: np.ndarray,
    free_r: np.ndarray,
    pos: int,
    m: int,
    i0: float,
    di0: tuple[float, float, float],
    fit_k: bool,
    sums: np.ndarray,
) -> None:
    """A segment's ``i0`` projected out of its residual and Jacobian rows, and their products
    added to ``sums`` (``J'J`` by rows ``rr, rl, ll``, ``J'r`` by ``r, l``, then ``rk, lk,
    kk`` and ``k``).

    Apart from the recursion, so that the sums may be reassociated (vectorised,
    as :func:`observer.estimation.kernels.score_products`): the residual and the
    Jacobian themselves are products taken element by element, the same either way.
    """
    di0_r, di0_l, di0_k = di0
    n_rr = n_rl = n_ll = n_rk = n_lk = n_kk = 0.0
    b_r = b_l = b_k = 0.0
    for i in range(m):
        gi = free[i]
        ig_r = i0 * free_r[i]
        r = out[pos + i] - i0 * gi
        f_r = jac[pos + i, 0]
        j_r = -f_r - (di0_r * gi + ig_r)
        j_l = (f_r + jac[pos + i, 1]) - (di0_l * gi - ig_r)
        out[pos + i] = r
        jac[pos + i, 0] = j_r
        jac[pos + i, 1] = j_l
        n_rr += j_r * j_r
        n_rl += j_r * j_l
        n_ll += j_l * j_l
        b_r += j_r * r
        b_l += j_l * r
        if fit_k:
            j_k = jac[pos + i, 2] - di0_k * gi
            jac[pos + i, 2] = j_k
            n_rk += j_r * j_k
            n_lk += j_l * j_k
            n_kk += j_k * j_k
            b_k += j_k * r
    sums[0] += n_rr
    sums[1] += n_rl
    sums[2] += n_ll
    sums[3] += b_r
    sums[4] += b_l
    sums[5] += n_rk
    sums[6] += n_lk
    sums[7] += n_kk
    sums[8] += b_k


# ---------------------------------------------------------------- reconstruction

#: Gauss-Legendre nodes on [0, 1] used to take moments of a reconstructed voltage.
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(6)
GAUSS_U = 0.5 * (_GAUSS_X + 1.0)
GAUSS_W = 0.5 * _GAUSS_W


@njit(nogil=True, cache=True)
def _cubic_point(v: np.ndarray, st: int, m: int, npts: int, x: float) -> float:
    """The segment's cubic (``npts`` samples nearest ``x``, all inside) at ``x`` (periods)."""
    lo = int(math.floor(x)) - 1
    if lo < 0:
        lo = 0
    if lo > m - npts:
        lo = m - npts
    val = 0.0
    for ia in range(npts):
        la = 1.0
        for ib in range(npts):
            if ib != ia:
                la *= (x - (lo + ib)) / (ia - ib)
        val += la * v[st + lo + ia]
    return val


@njit(nogil=True, cache=True)
def interpolated_moments(
    v: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    shift: float,
    gauss_u: np.ndarray,
    gauss_w: np.ndarray,
    out: np.ndarray,
) -> None:
    """Legendre moments of a piecewise-cubic reconstruction of sampled ``v``, per interval.

    Within each segment the voltage is the cubic (Lagrange) through the four
    samples nearest the point, all inside the segment (one-sided at its
    ends), evaluated ``shift`` sample periods later (a relative delay between
    the voltage and current channels; > 0: the voltage is read later).
    Intervals outside segments are left as they are in ``out``.

    Away from a segment's ends every interval sees the same cubic weights (they
    depend on ``shift`` only), so its moments are one fixed stencil of at most
    five samples, computed once per call; only the few intervals near the ends,
    where the cubic turns one-sided, evaluate it point by point.
    """
    n_nodes = gauss_u.shape[0]
    # Nodes lie inside (0, 1): their floors after the shift differ by at most one.
    base = int(math.floor(gauss_u[0] + shift))
    for gi in range(n_nodes):
        base = min(base, int(math.floor(gauss_u[gi] + shift)))
    # stencil[j, t]: weight of sample (k + base - 1 + t) in moment j of interval k.
    stencil = np.zeros((3, 5))
    top = base
    for gi in range(n_nodes):
        u = gauss_u[gi]
        o = int(math.floor(u + shift))
        top = max(top, o)
        frac = u + shift - o  # the node's position after sample k + o
        legendre = (1.0, 2.0 * u - 1.0, 6.0 * u * u - 6.0 * u + 1.0)
        for ia in range(4):
            la = 1.0
            for ib in range(4):
                if ib != ia:
                    la *= (frac + 1.0 - ib) / (ia - ib)
            for j in range(3):
                stencil[j, o - base + ia] += gauss_w[gi] * legendre[j] * la
    taps = top - base + 4
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        m = en - st + 1
        npts = 4 if m >= 4 else m
        for k in range(m - 1):
            first = k + base - 1
            if npts == 4 and first >= 0 and k + top - 1 <= m - 4:
                q0 = 0.0
                q1 = 0.0
                q2 = 0.0
                for t in range(taps):
                    x = v[st + first + t]
                    q0 += stencil[0, t] * x
                    q1 += stencil[1, t] * x
                    q2 += stencil[2, t] * x
            else:
                q0 = 0.0
                q1 = 0.0
                q2 = 0.0
                for gi in range(n_nodes):
                    u = gauss_u[gi]
                    wv = gauss_w[gi] * _cubic_point(v, st, m, npts, k + u + shift)
                    q0 += wv
                    q1 += wv * (2.0 * u - 1.0)
                    q2 += wv * (6.0 * u * u - 6.0 * u + 1.0)
            out[st + k, 0] = q0
            out[st + k, 1] = q1
            out[st + k, 2] = q2


@njit(nogil=True, cache=True)
def lowpass_segments(
    x: np.ndarray, lengths: np.ndarray, b: np.ndarray, a: np.ndarray, out: np.ndarray
) -> None:
    """A biquad ``(b, a)`` over each segment of ``x`` (``lengths`` in order), restarted."""
    pos = 0
    for s in range(lengths.shape[0]):
        m = lengths[s]
        x1 = 0.0
        x2 = 0.0
        y1 = 0.0
        y2 = 0.0
        for k in range(m):
            xi = x[pos + k]
            yi = b[0] * xi + b[1] * x1 + b[2] * x2 - a[1] * y1 - a[2] * y2
            out[pos + k] = yi
            x2 = x1
            x1 = xi
            y2 = y1
            y1 = yi
        pos += m


@njit(nogil=True, cache=True)
def lag_samples(
    mu: np.ndarray, v: np.ndarray, starts: np.ndarray, ends: np.ndarray, lag: float, out: np.ndarray
) -> None:
    """Samples of ``v`` through a first-order lag of ``lag`` sample periods, exactly per interval.

    ``mu`` holds the moments of ``v`` over each interval (its reconstruction
    between samples); each segment starts from rest at its first sample.
    """
    a, c0, c1, c2 = moment_coefficients(1.0, lag, 1.0)
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        x = v[st]
        out[st] = x
        for k in range(st, en):
            x = a * x + c0 * mu[k, 0] + c1 * mu[k, 1] + c2 * mu[k, 2]
            out[k + 1] = x
