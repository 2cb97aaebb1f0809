"""EMF speed from the tracked armature parameters, and the tachometer cross-check.

The armature equation ``va = Ra*ia + La*dia/dt + K*if*omega`` gives the speed
without a speed sensor: ``omega = (va - Ra*ia - La*dia/dt) / (K*if)``. Over a
window, per sample period (``va`` held, currents at its ends, as the
estimator's exact discretisation has it)

    omega_emf = sum(va_k - Ra*ia_mid_k - La*(ia_k+1 - ia_k)/dt) / (K * sum(if_mid_k))

the flux-weighted mean speed of the window; the measured speed is averaged the
same way, so the two agree exactly on an ideal machine. The EMF speed's
one-sigma comes from the tracked parameters' uncertainties.

A tachometer that slips or fails reads *low*: the armature equation then sees a
higher ``K`` (``K*if*omega`` is all it knows), and a tracker left alone would
learn the wrong ``K`` and agree with the faulty sensor. So a window where the
measured speed is below the EMF speed by more than ``tolerance`` (model error,
relative to the speed the armature voltage stands for) plus ``n_sigma`` sigmas is
*suspect*: the tracker does not take ``K`` from it, and after ``alarm_s`` of
suspect windows the tachometer is reported faulty (and cleared after as long
an agreement). A window short by several margins is stronger evidence than
one just beyond it: it counts as that many windows (a sensor that lost 10 %
against a 2 % margin is flagged within two windows), but never more than half
of ``alarm_s``, so no window alone raises the alarm. A sensor reading *high*
and a weakened field are the same thing to the armature equation; that case is
reported as a change of ``K`` (a field fault). Windows near standstill, where
a gain error of the sensor does not show, neither raise nor clear the alarm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from observer.config import SpeedConfig


@dataclass(frozen=True)
class SpeedEstimate:
    """One window's EMF speed and measured speed.

    Attributes
    ----------
    emf_rad_s, std_rad_s : float
        The EMF speed (flux-weighted window mean, rad/s) and its one-sigma.
    measured_rad_s : float or None
        The measured speed averaged the same way; None without a speed channel.
    measured_std_rad_s : float
        One-sigma of that mean from the sensor's noise (read from the second
        differences of the samples, which motion hardly reaches at kHz rates).
    scale_rad_s : float
        The speed the window's mean armature voltage stands for, ``|va| / (K*if)``:
        the scale of the armature equation's model error.
    """

    emf_rad_s: float
    std_rad_s: float
    measured_rad_s: float | None
    scale_rad_s: float
    measured_std_rad_s: float = 0.0


def emf_speed(
    va: np.ndarray,
    ia: np.ndarray,
    i_f: np.ndarray,
    omega: np.ndarray | None,
    dt: float,
    params: dict[str, tuple[float, float]],
) -> SpeedEstimate | None:
    """The window's EMF speed from ``Ra, La, K`` (``params``: name -> (value, relative std)).

    Returns None when the field current is too small for the flux to be known
    (no field, no EMF speed).
    """
    ra, ra_rel = params["Ra"]
    la, la_rel = params["La"]
    k, k_rel = params["K"]
    if va.size < 2:
        return None
    ia_mid = 0.5 * (ia[:-1] + ia[1:])
    if_mid = 0.5 * (i_f[:-1] + i_f[1:])
    a = float(np.sum(va[:-1]))
    b = float(np.sum(ia_mid))
    c = float(ia[-1] - ia[0]) / dt
    flux = k * float(np.sum(if_mid))
    if not abs(flux) > 1e-9 * max(abs(a), 1.0):
        return None
    speed = (a - ra * b - la * c) / flux
    var = (ra * b / flux * ra_rel) ** 2 + (la * c / flux * la_rel) ** 2 + (speed * k_rel) ** 2
    measured = None
    measured_std = 0.0
    if omega is not None:
        w_mid = 0.5 * (omega[:-1] + omega[1:])
        measured = float(np.sum(if_mid * w_mid) / np.sum(if_mid))
        if omega.size >= 3:
            # White noise of variance s^2 gives second differences of variance 6 s^2.
            noise_var = float(np.mean(np.square(np.diff(omega, 2)))) / 6.0
            measured_std = math.sqrt(noise_var / w_mid.size)
    return SpeedEstimate(
        speed, math.sqrt(var), measured, abs(a) / abs(flux), measured_std_rad_s=measured_std
    )


class TachometerCheck:
    """Measured speed against the EMF speed, window by window; events on a lasting disagreement.

    Parameters
    ----------
    config : SpeedConfig
    hop_s : float
        Time between windows (s): ``alarm_s`` is counted in windows that can
        tell (standstill windows neither extend nor break a run).
    """

    def __init__(self, config: SpeedConfig, hop_s: float) -> None:
        self.config = config
        self.faulty = False
        self.windows_needed = max(1, math.ceil(config.alarm_s / hop_s - 1e-9))
        # What one window can count towards them (in windows): half, so never one alone.
        self.most_per_window = max(1.0, 0.5 * self.windows_needed)
        self._run: list[int] = []  # window ends of the present run against the state
        self._weight = 0.0  # what the present run counts, in windows
        self.counts = {"suspect_windows": 0, "alarms": 0}

    def judge(self, speed: SpeedEstimate | None) -> bool | None:
        """True: the window is suspect (sensor reads low); False: agreement; None: can't tell."""
        depth = self.depth(speed)
        return None if depth is None else depth > 1.0

    def depth(self, speed: SpeedEstimate | None) -> float | None:
        """How far the measured speed reads below the EMF speed, in margins
        (``tolerance * scale + n_sigma * sigma``); None where a window cannot tell."""
        if speed is None or speed.measured_rad_s is None:
            return None
        cfg = self.config
        sigma = math.hypot(speed.std_rad_s, speed.measured_std_rad_s)
        margin = cfg.tolerance * speed.scale_rad_s + cfg.n_sigma * sigma
        if not margin > 0 or margin > cfg.min_loss * abs(speed.emf_rad_s):
            return None  # near standstill a gain error does not show
        deficit = math.copysign(1.0, speed.emf_rad_s) * (speed.emf_rad_s - speed.measured_rad_s)
        return deficit / margin

    def update(
        self, t_ns: int, speed: SpeedEstimate | None
    ) -> tuple[bool | None, dict[str, Any] | None]:
        """Take one window: whether it is suspect (see :meth:`judge`), and an event dict
        when the alarm is raised or cleared (else None)."""
        if not self.config.check_tachometer:
            return None, None
        depth = self.depth(speed)
        if depth is None:
            return None, None
        suspect = depth > 1.0
        if suspect:
            self.counts["suspect_windows"] += 1
        if suspect == self.faulty:  # the present state confirmed: no run towards a change
            self._run.clear()
            self._weight = 0.0
            return suspect, None
        self._run.append(t_ns)
        self._weight += min(depth, self.most_per_window) if suspect else 1.0
        if self._weight < self.windows_needed - 1e-9:
            return suspect, None
        since = self._run[0]
        self._run.clear()
        self._weight = 0.0
        self.faulty = suspect
        assert speed is not None and speed.measured_rad_s is not None
        relative = speed.measured_rad_s / speed.emf_rad_s - 1.0
        if suspect:
            self.counts["alarms"] += 1
            message = (
                f"measured speed {speed.measured_rad_s:.1f} rad/s reads {100 * -relative:.1f} % "
                f"below the EMF speed {speed.emf_rad_s:.1f} rad/s since "
                f"{since / 1e9:.2f} s: tachometer slipping or failed?"
            )
        else:
            message = f"measured speed agrees with the EMF speed again since {since / 1e9:.2f} s"
        event = {
            "kind": "tachometer",
            "state": "fault" if suspect else "cleared",
            "t_ns": int(t_ns),
            "since_ns": int(since),
            "measured_rad_s": speed.measured_rad_s,
            "emf_rad_s": speed.emf_rad_s,
            "emf_std_rad_s": speed.std_rad_s,
            "relative": relative,
            "message": message,
        }
        return suspect, event

    def distrusts_k(self, suspect: bool | None) -> bool:
        """Whether ``K`` must not be learnt now: the alarm is on or this window is suspect."""
        return self.faulty or bool(suspect)
