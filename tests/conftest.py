"""Shared fixtures: simulated motors are expensive, so they are made once per session."""

from __future__ import annotations

import os

import pytest

# parallel_circuits = "auto" starts a second process per observer on a machine with two
# CPUs: the suite's hundreds of short observers would each start one. Tests of the worker
# ask for it ("on", or parallel=True); the numbers are the same either way.
os.environ.setdefault("DCOBSERVER_PARALLEL_CIRCUITS", "off")

from observer.estimation.motor import P12, TRACTION_60V
from observer.simulation.simulate import simulate
from tests.peers import Child
from tests.pki import OPENSSL, Pki


@pytest.fixture(scope="session")
def p12_recording():
    """12 s of the P-12 in duty-cycle operation, 2 kHz, 0.2 % sensor noise."""
    return simulate(P12, duration_s=12.0, sample_rate_hz=2000.0, noise=0.002, seed=3)


@pytest.fixture(scope="session")
def traction_recording():
    """12 s of a 60 V / 16 mOhm traction motor, 2 kHz, 0.2 % sensor noise."""
    return simulate(TRACTION_60V, duration_s=12.0, sample_rate_hz=2000.0, noise=0.002, seed=4)


@pytest.fixture
def children():
    """Start real peers: ``children(args, ...)`` is a :class:`tests.peers.Child`; all are
    killed at the end of the test."""
    started: list[Child] = []

    def start(args, **kwargs):
        child = Child(args, **kwargs)
        started.append(child)
        return child

    yield start
    for child in started:
        child.kill()


@pytest.fixture(scope="session")
def pki(tmp_path_factory):
    """A test certificate authority (and a second, unrelated one): :class:`tests.pki.Pki`."""
    if OPENSSL is None:
        pytest.skip("needs the openssl command")
    return Pki(tmp_path_factory.mktemp("pki"))


@pytest.fixture(scope="session")
def p12_adc_recording(p12_recording):
    """The P-12 recording as a 12-bit drive ADC measures it (+-2.5x rated), with "adc" metadata."""
    from bench.common import adc_full_scale
    from observer.recording import quantise

    return quantise(p12_recording, adc_full_scale(P12), bits=12)
