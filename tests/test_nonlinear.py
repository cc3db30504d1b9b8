"""Nonlinear maths: closed-form predictors and exact steps against direct ODE solves,
the laws against the errata, and the controllers' contracts (no FMI)."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from delaycomp.maths.history import InputHistory
from delaycomp.maths.lti import flow
from delaycomp.maths.model import ModelError, load_model
from delaycomp.maths.nlcontrol import ContinuousController, ModelPlant, ZOHModelController
from delaycomp.maths.predictors import (
    _unit_deadbeat_gain,
    bilinear_predictor,
    deadbeat_gain,
    integrate,
    numerical_predictor,
)
from delaycomp.paper.models import example_2_4, example_3_8, proposition_4_2, unicycle
from delaycomp.paper.models import path as model_path

# Direct solves at rtol = atol = 1e-12 are accurate to ~1e-10 on these O(1) problems over
# a few seconds; closed forms must agree with them to 1e-8.
ODE = 1e-12
VS_ODE = 1e-8


def direct(f, p, x, segments):
    z = np.array(x, dtype=float)
    for d, u in segments:
        sol = solve_ivp(lambda _t, s, u=u: f(s, np.asarray(u, float), p), (0, d), z,
                        method="DOP853", rtol=ODE, atol=ODE)
        z = sol.y[:, -1]
    return z


def random_segments(seed, m, total=1.7, count=7, scale=1.0):
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.uniform(0, total, count - 1))
    d = np.diff(np.concatenate([[0.0], cuts, [total]]))
    return [(float(di), rng.normal(size=m) * scale) for di in d], rng


@pytest.mark.parametrize("seed", range(4))
def test_example_2_4_closed_form_2_16_2_17(seed):
    segments, rng = random_segments(seed, 1)
    x = rng.normal(size=3)
    closed = example_2_4.predictor(x, segments, {})
    np.testing.assert_allclose(closed, direct(example_2_4.f, {}, x, segments),
                               rtol=VS_ODE, atol=VS_ODE)
    np.testing.assert_allclose(example_2_4.step(x, segments[0][1], segments[0][0], {}),
                               direct(example_2_4.f, {}, x, segments[:1]), rtol=VS_ODE,
                               atol=VS_ODE)


@pytest.mark.parametrize("shape", ["square", "sin"])
def test_example_3_8_predictor_through_theta_and_exact_step(shape):
    p = {"p": shape, "T": 1.0}
    segments, rng = random_segments(11, 1)
    x = rng.normal(size=2)
    np.testing.assert_allclose(example_3_8.predictor(x, segments, p),
                               direct(example_3_8.f, p, x, segments), rtol=VS_ODE, atol=VS_ODE)
    np.testing.assert_allclose(example_3_8.step(x, [0.7], 0.9, p),
                               direct(example_3_8.f, p, x, [(0.9, [0.7])]), rtol=VS_ODE,
                               atol=VS_ODE)


def test_example_3_8_law_is_3_30_for_r_below_T():
    """(3.30) for tau = 0, 0 < r < T, p(w) = w^2: the chain predictor applied to (3.29)."""
    T, r, u_prev = 1.0, 0.4, 0.3
    p = {"p": "square", "T": T}
    y = np.array([0.8, -0.6])
    u = example_3_8.k(example_3_8.predictor(y, [(r, [u_prev])], p), p)[0]
    x1, x2 = y
    printed = (-x1 / T**2 + x2**3 / 3 / T**2 - (3 * T + 2 * r) / (2 * T**2) * x2
               - r * (r + 3 * T) / (2 * T**2) * u_prev)
    assert u == pytest.approx(printed, rel=1e-13)


@pytest.mark.parametrize("seed", range(3))
def test_unicycle_exact_flow_and_predictor_4_12(seed):
    segments, rng = random_segments(seed + 20, 2, scale=1.5)
    s = rng.normal(size=3)
    np.testing.assert_allclose(unicycle.predict(s, segments),
                               direct(lambda z, u, p: unicycle.dynamics(z, u), {}, s, segments),
                               rtol=VS_ODE, atol=VS_ODE)


def test_bilinear_closed_form_remark_2_2_d_ii():
    rng = np.random.default_rng(5)
    A = np.diag([0.3, -0.5]) + 0.0
    C = np.diag([0.7, 0.2])          # diagonal: AC = CA
    B = rng.normal(size=(2, 1))
    phi = bilinear_predictor(A, B, C)
    segments, _ = random_segments(6, 1)
    x = rng.normal(size=2)

    def f(z, u, p):
        return A @ z + (B @ u) + u[0] * (C @ z)

    np.testing.assert_allclose(phi(x, segments, {}), direct(f, {}, x, segments), rtol=VS_ODE,
                               atol=VS_ODE)
    with pytest.raises(ValueError, match="AC = CA"):
        bilinear_predictor(A, B, np.array([[0.0, 1.0], [0.0, 0.0]]))


def test_numerical_predictor_matches_closed_forms():
    segments, rng = random_segments(8, 1)
    x = rng.normal(size=3)
    phi = numerical_predictor(example_2_4.f, 1e-11, 1e-11)
    np.testing.assert_allclose(phi(x, segments, {}), example_2_4.predictor(x, segments, {}),
                               rtol=VS_ODE, atol=VS_ODE)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_deadbeat_gain_makes_the_sampled_chain_nilpotent(n):
    T = 0.7
    K = deadbeat_gain(n, T)
    Ad, Bd = flow(np.eye(n, k=1), np.eye(n)[:, -1:], T)
    M = Ad + Bd @ K
    assert np.max(np.abs(np.linalg.matrix_power(M, n))) < 1e-9 * max(1, np.abs(M).max()) ** n
    if n == 2:
        np.testing.assert_allclose(K, [[-1 / T**2, -3 / (2 * T)]], rtol=1e-12)


@pytest.mark.parametrize("T", [1.0, 0.7, 0.25, 3.0])
def test_deadbeat_gain_is_the_nearest_float_to_the_exact_gain(T):
    """The gain is computed in exact rationals, so it is the same on every machine: for
    n = 1, 2, 3 it is the nearest float to the closed forms -1/T, -(1/T^2, 3/(2T)) and
    -(1/T^3, 2/T^2, 11/(6T)) (no tolerance: one correctly rounded division each)."""
    t = Fraction(T)
    closed = {1: [-1 / t], 2: [-1 / t**2, Fraction(-3, 2) / t],
              3: [-1 / t**3, -2 / t**2, Fraction(-11, 6) / t]}
    for n, exact in closed.items():
        assert deadbeat_gain(n, T).tolist() == [[float(k) for k in exact]]


@pytest.mark.parametrize("n", [1, 4, 8, 12])
def test_unit_deadbeat_gain_makes_the_rational_chain_exactly_nilpotent(n):
    """For T = 1 the discretized chain has rational entries (1/k!): with the rational gain,
    ``(Ad + Bd K)^n`` is exactly zero (where floating-point Ackermann loses digits as n
    grows: measured 2e-4 relative error of K at n = 12)."""
    K = _unit_deadbeat_gain(n)
    M = [[Fraction(1, math.factorial(j - i)) if j >= i else Fraction(0) for j in range(n)]
         for i in range(n)]
    for i in range(n):
        for j in range(n):
            M[i][j] += Fraction(1, math.factorial(n - i)) * K[j]
    P = M
    for _ in range(n - 1):
        P = [[sum((P[i][k] * M[k][j] for k in range(n)), Fraction(0)) for j in range(n)]
             for i in range(n)]
    assert all(v == 0 for row in P for v in row)


def test_corrected_2_18_is_the_errata_forwarding_law_and_printed_differs():
    rng = np.random.default_rng(1)
    for x in rng.normal(size=(20, 3)) * 2:
        x1, x2, x3 = x
        xi2 = x2 - x3**2 / 2
        eta2 = xi2 + x3
        eta1 = x1 + 2 * eta2 - x3 + 0.75 * x3**2 - 0.75 * x3 * eta2 + 0.375 * eta2**2
        forwarding = -(eta2 + x3) - (1 + 0.75 * x3) * eta1
        corrected = example_2_4.k(0.0, x, {"law": "corrected"})[0]
        printed = example_2_4.k(0.0, x, {"law": "printed"})[0]
        assert corrected == pytest.approx(forwarding, rel=1e-12, abs=1e-12)
        assert corrected - printed == pytest.approx(3 / 32 * x3**4, rel=1e-10, abs=1e-12)


def test_printed_2_18_escapes_in_finite_time_from_the_errata_state():
    x0 = [-1.295, 2.307, -4.261]
    sol = solve_ivp(lambda t, x: example_2_4.f(x, example_2_4.k(t, x, {"law": "printed"}), {}),
                    (0, 1.0), x0, rtol=1e-10, atol=1e-10)
    assert sol.status == -1 or sol.t[-1] < 0.25 or np.abs(sol.y[:, -1]).max() > 1e6


def test_corrected_unicycle_law_is_deadbeat_in_3T_and_printed_is_not():
    rng = np.random.default_rng(3)
    worst = 0.0
    for s in rng.normal(size=(100, 3)) * 2:
        for _ in range(3):
            s = unicycle.flow(s, proposition_4_2.k(s, {"T": 1.0, "law": "corrected"}), 1.0)
        worst = max(worst, np.abs(s).max())
    assert worst < 1e-12
    s = np.array([1.0, 1.0, 0.5])
    for _ in range(3):
        s = unicycle.flow(s, proposition_4_2.k(s, {"T": 1.0, "law": "printed"}), 1.0)
    assert np.abs(s).max() > 1e-3


def test_history_segments_merge_and_bound():
    hist = InputHistory(5, 0.1, [2.0])
    assert [(round(d, 12), u.tolist()) for d, u in hist.segments()] == [(0.5, [2.0])]
    for v in (1.0, 1.0, 3.0):
        hist.push([v])
    assert [(round(d, 12), u.tolist()) for d, u in hist.segments()] == [
        (0.2, [2.0]), (0.2, [1.0]), (0.1, [3.0])]
    for _ in range(100):
        hist.push([0.0])
    assert len(hist.values) == 5


def loop(model, ctrl, plant, r, tau, h, x0, u0, ticks):
    """In-process loop: plant -> delay r -> controller -> delay tau -> plant (exact grid)."""
    from delaycomp.maths.delayline import DelayLine

    meas = DelayLine(model.n, round(r / h), x0)
    act = DelayLine(model.m, round(tau / h), u0)
    xs, us = [], []
    for _ in range(ticks):
        y = np.array(meas.output(plant.x))
        u = ctrl.output(y)
        applied = act.output(u)
        xs.append(plant.x.copy())
        us.append(u.copy())
        meas.push(plant.x)
        ctrl.advance(y)
        act.push(u)
        plant.step(np.array(applied), h)
    return np.array(xs), np.array(us)


def test_continuous_controller_state_is_the_plant_state_tau_ahead():
    """(2.10): after the first reset with iT >= r, z(t) = x(t + tau) exactly (to the
    closed forms' round-off), since z is integrated with the inputs the plant will get."""
    model = load_model(model_path("example_2_4"))
    T, r, tau, N = 0.5, 0.3, 0.7, 50
    h = T / N
    ctrl = ContinuousController(model, model.params(), T, r, tau, N, [0.0], [1.0, -1.0, 0.5])
    plant = ModelPlant(model, model.params(), [1.0, -1.0, 0.5])
    zs = []
    orig = ctrl.advance

    def spy(y):
        orig(y)
        zs.append(ctrl.z.copy())  # z(t_{k+1})
    ctrl.advance = spy
    xs, _ = loop(model, ctrl, plant, r, tau, h, [1.0, -1.0, 0.5], [0.0], 8 * N)
    D = round(tau / h)
    first = N  # the reset at t = T (T >= r) is exact
    for k in range(first, len(zs) - D - 1):
        np.testing.assert_allclose(zs[k], xs[k + 1 + D], rtol=1e-10, atol=1e-12)


def test_zoh_controller_refuses_tau_off_the_period_unless_padded():
    model = load_model(model_path("example_3_8"))
    with pytest.raises(ValueError, match=r"tau = 0\.5 is not allowed"):
        ZOHModelController(model, model.params(), 1.0, 0.5, 0.5, 10, [0.0])
    ctrl = ZOHModelController(model, model.params(), 1.0, 0.5, 0.5, 10, [0.0], pad=True)
    assert ctrl.tau_effective == 1.0 and ctrl.padding == pytest.approx(0.5)


def test_padded_zoh_loop_is_deadbeat_shifted():
    """tau = 0.5 T padded to T: dead-beat at (l + ceil(r/T) + 2) T with l = 1."""
    model = load_model(model_path("example_3_8"))
    T, r, tau, N = 1.0, 0.5, 0.5, 20
    ctrl = ZOHModelController(model, model.params(), T, r, tau, N, [0.0], pad=True)
    plant = ModelPlant(model, model.params(), [1.0, -1.0])
    xs, _ = loop(model, ctrl, plant, r, tau, T / N, [1.0, -1.0], [0.0], 8 * N)
    assert np.abs(xs[4 * N:]).max() < 1e-12
    assert np.abs(xs[4 * N - 1]).max() > 1e-6


def test_model_interface_errors_are_named(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("STATES = ('x',)\nINPUTS = ('u',)\nCONTROL = 'zoh'\n"
                   "def f(x, u, p): return -x\n", encoding="utf-8")
    with pytest.raises(ModelError, match="missing k"):
        load_model(bad)
    bad.write_text("STATES = ('x',)\nINPUTS = ('u',)\nCONTROL = 'zoh'\n"
                   "def f(x, u, p): return -x\ndef k(t, x, p): return -x\n", encoding="utf-8")
    with pytest.raises(ModelError, match=r"needs k\(x, p\)"):
        load_model(bad)
    with pytest.raises(ModelError, match="not a Python file"):
        load_model(tmp_path / "missing.py")


def test_numerical_integration_reports_failure():
    def blowup(x, u, p):
        return x * x

    with pytest.raises(RuntimeError, match="ODE solve failed"):
        integrate(blowup, {}, [10.0], [(1.0, [0.0])])

