"""The in-process engine against the FMU engine: same slaves, same master, same numbers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.paper.scenarios import lti_loop
from delaycomp.studies import sweep
from delaycomp.studies.axes import parse_grid
from delaycomp.studies.sweep import SweepOptions

from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close, assert_same_values

pytestmark = pytest.mark.fmu

# A few non-default settings on top of the defaults, so that every controller family and
# predictor path runs in both engines (numerical Phi, padding, uncompensated, delays).
VARIANTS = {
    "example-3.6": [],
    "example-3.6-uncompensated": ["mode=uncompensated", "r=0.3", "tau=1"],
    "example-2.4": [],
    "example-2.4-numerical": ["predictor=numerical", "T=1"],
    "example-3.8": [],
    "example-3.8-padded": ["tau=0.5", "pad=1", "p=sin"],
    "corollary-3.7": [],
    "corollary-4.1": [],
    "proposition-4.2": [],
    "proposition-4.2-printed": ["law=printed", "u0=0.3,-0.2"],
}


def _scenario(case: str) -> str:
    return next(name for name in scenarios.SCENARIOS if case.startswith(name))


@pytest.mark.parametrize("case", sorted(VARIANTS))
def test_inprocess_engine_equals_fmu_engine(fmu_dir, case):
    """Both engines call the same slave classes in the same order: any difference would
    be a difference in the code path, not round-off. 1e-12 (absolute, relative to
    ``1 + |x|``) is the issue's bound; the measured difference is exactly 0."""
    sc = scenarios.get(_scenario(case))
    spec = sc.make(sc.resolve(VARIANTS[case]))
    stop = min(sc.default_stop_time, 30.0)
    fmu = run_loop(spec, stop, fmu_dir)
    inproc = run_loop(spec, stop, engine="inprocess")
    assert fmu.success and inproc.success, (fmu.message, inproc.message)
    assert inproc.names == fmu.names
    assert_columns_close(inproc.times, fmu.times, SAME_ARITHMETIC_ULPS, "time")
    err = np.abs(inproc.data - fmu.data)
    assert np.all(err <= 1e-12 * (1 + np.abs(fmu.data))), f"largest difference {err.max():.3e}"
    assert inproc.notes == fmu.notes


def test_inprocess_engine_refuses_what_the_fmu_refuses(fmu_dir):
    """A bad parameter stops both engines with the same one-line reason, naming it. (The
    typed loop refuses ``tau = 0.5`` itself; set on the instance afterwards, as a host
    would set it, the FMU is the one to refuse it.)"""
    spec = lti_loop([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, tau=0.0, N=10,
                    mode="compensated", x0=[1.0], u0=[0.0]).set_parameters("controller",
                                                                           tau=0.5)
    fmu = run_loop(spec, 2.0, fmu_dir)
    inproc = run_loop(spec, 2.0, engine="inprocess")
    assert not fmu.success and not inproc.success
    assert "tau = 0.5 is not allowed" in inproc.message
    assert inproc.message == fmu.message


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_inprocess_engine_reports_a_diverging_plant_with_time_and_keeps_the_rows():
    """x' = 50 x overflows near t = 14; the plant refuses the step, the master stops naming
    it and the time, and the rows recorded so far are kept. (numpy warns of the overflow;
    this suite turns warnings into errors, so the warning is let through here as a host
    would.)"""
    spec = lti_loop([[50.0]], [[1.0]], [[0.0]], T=1.0, r=0.0, tau=0.0, N=10,
                    mode="uncompensated", x0=[1.0], u0=[0.0])
    res = run_loop(spec, 100.0, engine="inprocess")
    assert not res.success
    assert res.message.startswith("plant failed at t = ")
    assert "is not allowed: must be finite (the plant diverged" in res.message
    assert 10 < len(res.times) < 1001 and np.all(np.isfinite(res.data))


def test_sweep_inprocess_equals_fmu(fmu_dir):
    axes = [parse_grid("r=0.1:0.3:3")]
    options = SweepOptions(stop=5.0, fmu_dir=str(fmu_dir))
    inprocess = dataclasses.replace(options, engine="inprocess")
    assert_same_values(sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"], inprocess),
                       sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"], options),
                       SAME_ARITHMETIC_ULPS, "rows")
