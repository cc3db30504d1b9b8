"""The time-stamp controller for model (nonlinear) plants: ``StampedModelController``.

Held against an independent simulation: the plant ``x' = f(x, u)`` written out here (not
the model file's ``f``) and solved by ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-12,
atol 1e-14) over each base step ``h`` with the input it receives then (the controller's
output ``tau`` later); its state measured through a network channel (``ChannelLine``:
jitter larger than ``T``, 30 % of the packets lost). The controller's prediction ``x_hat``
at ``t_i`` must be the plant's ``x(t_i + tau)``.

Tolerance: the controller integrates the model with DOP853 at ``rtol = atol = tol``
(``1e-10``, the nonlinear controllers' default) over at most ``(age_max + tau) / T + 2``
input pieces; each solve's local error is kept near ``tol`` relative to the state, and
the pieces compose over a window of ``age_max + tau`` seconds, where this plant's flow
amplifies an error by at most ``e^{L (age_max + tau)}`` (a factor of a few here). So
``100 tol`` of the state's size bounds the prediction error with room to spare
(measured, relative to max |x| = 5: 1.7e-12 at tol = 1e-10, 1.8e-10 at 1e-8, 1.3e-8 at
1e-6: the error follows the tolerance), and the independent reference is two decades
tighter than ``tol``. The same run with the age assumed constant (stamps ignored) is off by
``1e-3`` or more, so the check can fail.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are

from delaycomp.maths.channel import Channel, ChannelLine
from delaycomp.maths.model import Model, load_model
from delaycomp.maths.stamped import StampedController, StampedModelController
from delaycomp.paper import models

T, N = 0.5, 10
H = T / N
TOL = 1e-10
#: Example 3.8, p(w) = sin(w): nonlinear in both the flow and Theta
EX38 = load_model(models.path("example_3_8"))
PARAMS = {"p": "sin"}
X0 = [2.0, -3.0]


def _f(x, u):
    """Example 3.8 with p = sin, (3.27), written out here: the reference's plant."""
    return np.array([x[1] + math.sin(x[1]) * u[0], u[0]])


def _excitation(i: int) -> np.ndarray:
    """A probing signal added to the control, so the state stays away from 0 (the law is
    dead-beat): the prediction must hold whatever the plant receives."""
    return np.array([2.0 * math.sin(0.7 * i) + math.cos(1.9 * i)])


def _run(ctrl, channel: Channel, tau: float, steps: int, x0, f=_f, shadow=None):
    """Plant + channel + controller on the grid ``h``. Returns the predictions ``(k,
    x_hat, u)`` at the sampling instants, the plant's states at every step and the ages
    of the samples. ``shadow``: ``(controller, age)``, a second controller that sees the
    same samples stamped ``t - age`` (it assumes a constant age) and stores the same
    outputs; its predictions are returned instead."""
    x0 = np.asarray(x0, dtype=float)
    D = round(tau / H)
    line = ChannelLine(channel, len(x0), H, list(x0))
    u0 = ctrl.held.copy()
    outputs, xs, preds, ages = [], [x0], [], []
    x = x0
    for k in range(steps):
        y, stamp = line.step(list(x))
        if k % N == 0:
            x_hat = ctrl.predict(y, stamp)
            u = ctrl.propose(y, stamp)
            ages.append(k * H - stamp)
            held = u + _excitation(k // N)
            ctrl.commit(held, y, stamp)
            if shadow is not None:
                other, age = shadow
                x_hat = other.predict(y, k * H - age)
                other.commit(held, y, k * H - age)
            preds.append((k, x_hat, u))
        outputs.append(ctrl.held)
        applied = outputs[k - D] if k >= D else u0
        sol = solve_ivp(lambda _t, z, v=applied: f(z, v), (0.0, H), x, method="DOP853",
                        rtol=1e-12, atol=1e-14)
        x = sol.y[:, -1]
        xs.append(x)
    return preds, np.array(xs), np.array(ages)


def _channel(policy="in_order", seed=4):
    # a packet every 3 h (T = 10 h), delays uniform in [0.1, 0.8]: jitter 1.4 T, packets overtake
    # each other; lost ones leave the controller predicting from its last estimate
    return Channel(delay=0.1, distribution="uniform", jitter=0.7, loss_model="bernoulli",
                   loss=0.3, policy=policy, seed=seed, period=3 * H)


def _worst(preds, xs, tau, steps):
    D = round(tau / H)
    return max(np.abs(x_hat - xs[k + D]).max() for k, x_hat, _ in preds if k + D <= steps)


@pytest.mark.parametrize("policy", ["in_order", "drop_stale"])
@pytest.mark.parametrize("tau", [0.5, 0.35])
def test_the_prediction_of_a_nonlinear_plant_is_at_the_solver_tolerance(policy, tau):
    """Example 3.8 over a lossy, jittered channel: ``x_hat`` is the plant's ``x(t_i + tau)``
    to ``100 tol`` of the state's size at every sampling instant (``tau`` need not be a
    multiple of ``T``), and the output is the model's law at ``x_hat``."""
    steps = 400
    ctrl = StampedModelController(EX38, PARAMS, T, tau, 1.0, "compensated", [0.0], tol=TOL)
    preds, xs, ages = _run(ctrl, _channel(policy), tau, steps + 20, X0)
    scale = np.abs(xs).max()
    worst = _worst(preds, xs, tau, steps)
    assert worst <= 100 * TOL * scale, worst / scale
    assert ages.max() > T and len(np.unique(np.round(ages, 9))) > 5  # jitter and loss
    p = {**PARAMS, "T": T}
    for _, x_hat, u in preds:
        assert np.array_equal(u, EX38.k(x_hat, p))


def test_ignoring_the_stamps_is_not_exact_there():
    """The same loop, and a controller beside it told a constant age (the channel's least
    delay): its predictions are off by far more than the solver's tolerance, so the test
    above can fail."""
    steps = 300

    def make():
        return StampedModelController(EX38, PARAMS, T, 0.5, 1.0, "compensated", [0.0],
                                      tol=TOL)

    preds, xs, _ = _run(make(), _channel(), 0.5, steps + 20, X0,
                        shadow=(make(), 0.1))
    assert _worst(preds, xs, 0.5, steps) >= 1e-3 * np.abs(xs).max()


def test_the_error_follows_the_tolerance():
    """A looser tolerance gives a larger error, still within ``100 tol``: the error is the
    integrator's, not the controller's bookkeeping."""
    steps, tau = 300, 0.5
    errors = {}
    for tol in (1e-6, 1e-10):
        ctrl = StampedModelController(EX38, PARAMS, T, tau, 1.0, "compensated", [0.0],
                                      tol=tol)
        preds, xs, _ = _run(ctrl, _channel(), tau, steps + 20, X0)
        errors[tol] = _worst(preds, xs, tau, steps) / np.abs(xs).max()
        assert errors[tol] <= 100 * tol, errors
    assert errors[1e-6] > 100 * errors[1e-10], errors  # measured: 1.3e-8 and 1.7e-12


# -- an LTI plant written as a model: the same as StampedController ----------------------
def _lti():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 3)) * 0.8 + 0.3 * np.eye(3)
    B = rng.normal(size=(3, 2))
    P = solve_continuous_are(A, B, np.eye(3), np.eye(2))
    K = -(B.T @ P)  # the paper's sign, u = K x
    model = Model("lti3", ("x1", "x2", "x3"), ("u1", "u2"), "zoh",
                  lambda x, u, p: A @ x + B @ u, lambda x, p: K @ x)
    return A, B, K, model


def test_an_lti_model_is_the_lti_controller():
    """Both controllers on the same samples (a lossy channel with jitter 1.4 T), the
    outputs of the LTI one committed to both: the same decisions, and predictions equal
    to the solves' tolerance (``100 tol`` of the state's size; the LTI one is exact)."""
    A, B, K, model = _lti()
    tau, age_max, u0 = 0.35, 1.0, [0.2, -0.1]
    exact = StampedController(A, B, K, T, tau, age_max, "compensated", u0)
    ctrl = StampedModelController(model, {}, T, tau, age_max, "compensated", u0, tol=TOL)
    assert ctrl.L == exact.L
    line = ChannelLine(_channel(), 3, H, [1.0, -0.5, 0.3])
    x = np.array([1.0, -0.5, 0.3])
    D = round(tau / H)
    outputs, scale, worst, decisions = [], 0.0, 0.0, []
    for k in range(400):
        y, stamp = line.step(list(x))
        if k % N == 0:
            a, b = exact.predict(y, stamp), ctrl.predict(y, stamp)
            worst = max(worst, np.abs(a - b).max())
            decisions.append((exact.estimate(y, stamp)[1], ctrl.estimate(y, stamp)[1]))
            u = exact.propose(y, stamp)
            assert np.abs(ctrl.propose(y, stamp) - u).max() <= 100 * TOL * (
                1 + np.abs(K).sum(axis=1).max() * np.abs(a).max())
            exact.commit(u, y, stamp)
            ctrl.commit(u, y, stamp)
            assert ctrl.stamp == exact.stamp
        outputs.append(exact.held)
        applied = outputs[k - D] if k >= D else np.asarray(u0)
        sol = solve_ivp(lambda _t, z, v=applied: A @ z + B @ v, (0.0, H), x,
                        method="DOP853", rtol=1e-12, atol=1e-14)
        x = sol.y[:, -1]
        scale = max(scale, np.abs(x).max())
    assert all(a == b for a, b in decisions)
    assert {a for a, _ in decisions} == {True, False}  # samples used and samples not
    assert worst <= 100 * TOL * scale, worst / scale


def test_uncompensated_is_the_law_on_the_sample():
    c = StampedModelController(EX38, PARAMS, T, 0.5, 1.0, "uncompensated", [0.0])
    y = np.array([0.3, -0.2])
    assert np.array_equal(c.propose(y, -0.1), EX38.k(y, {**PARAMS, "T": T}))


def test_the_state_restores_the_run():
    def make():
        return StampedModelController(EX38, PARAMS, T, 0.5, 1.0, "compensated", [0.0])

    a = make()
    rng = np.random.default_rng(1)
    samples = [(rng.normal(size=2), i * T - 0.1 * (1 + i % 4)) for i in range(30)]
    for y, s in samples[:12]:
        a.commit(a.propose(y, s), y, s)
    b = make()
    b.set_state(a.get_state())
    for y, s in samples[12:]:
        ua, ub = a.propose(y, s), b.propose(y, s)
        assert np.array_equal(ua, ub)
        a.commit(ua, y, s)
        b.commit(ub, y, s)


@pytest.mark.parametrize("kwargs, message", [
    ({"T": 0.0}, "T = 0.0 is not allowed: must be a finite number > 0"),
    ({"tau": -0.1}, "tau = -0.1 is not allowed: must be a finite number >= 0.0"),
    ({"age_max": math.inf}, "age_max = inf is not allowed"),
    ({"mode": "x"}, "mode = 'x' is not allowed: must be one of compensated, uncompensated"),
    ({"tol": 0.0}, "tol = 0.0 is not allowed: must be a number > 0 and < 1"),
    ({"tol": math.nan}, "tol = nan is not allowed: must be a number > 0 and < 1"),
    ({"model": load_model(models.path("example_2_4"))},
     "model = 'example_2_4' is not allowed: its CONTROL is 'continuous'"),
])
def test_bad_parameters_are_named(kwargs, message):
    args = {"model": EX38, "params": PARAMS, "T": T, "tau": 0.5, "age_max": 1.0,
            "mode": "compensated", "u0": [0.0], **kwargs}
    with pytest.raises(ValueError, match=message.replace("(", r"\(")) as err:
        StampedModelController(**args)
    assert "\n" not in str(err.value)


def test_a_stamp_from_the_future_is_refused():
    c = StampedModelController(EX38, PARAMS, T, 0.5, 1.0, "compensated", [0.0])
    with pytest.raises(ValueError, match=r"stamp = 0.5 at t = 0.0 is not allowed"):
        c.propose([1.0, 0.0], 0.5)
