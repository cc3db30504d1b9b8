"""The time-stamp controller's maths (issue 29, item 2): ``delaycomp.maths.stamped``.

Held against an independent simulation: the plant on the base grid ``h`` by its own
exact discretization (``scipy.linalg.expm`` of the augmented matrix, written out here),
its input the controller's output ``tau`` later, its measurement through a network
channel (``ChannelLine``: jitter larger than ``T``, 30 % loss). The controller's
prediction ``x_hat`` at ``t_i`` must be the plant's ``x(t_i + tau)``.

Tolerance: both sides compose exact flows (matrix exponentials, each accurate to a few
ulps of its norm) over at most ``(age_max + tau) / h`` pieces, with states of size
``O(max |x|)``; the error is round-off, a few hundred ulps of ``max |x|`` at most: the
tests allow ``1e-11 max |x|`` (they measure ~1e-14), while the controller that assumes
the nominal delay is off by 1e-3 or more in the same runs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm, solve_continuous_are

from delaycomp.maths.channel import Channel, ChannelLine
from delaycomp.maths.lti import LTIPredictor
from delaycomp.maths.stamped import StampedController

T, N = 0.1, 10
H = T / N


def _plant(seed: int = 0):
    """An unstable n = 3, m = 2 plant and an LQR gain (the paper's sign, u = K x)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 3)) * 0.8 + 0.3 * np.eye(3)
    B = rng.normal(size=(3, 2))
    P = solve_continuous_are(A, B, np.eye(3), np.eye(2))
    return A, B, -(B.T @ P)


def _zoh(A, B, h):
    """The plant's exact step, from scipy alone."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    F = expm(M * h)
    return F[:n, :n], F[:n, n:]


def _closed_loop(channel: Channel, tau: float, steps: int, stamped: bool = True,
                 age_max: float = 0.6, seed: int = 0):
    """Run plant + channel + controller on the grid; the predictions at the sampling
    instants ``(i, x_hat)``, the plant's states at every step, and the samples' ages."""
    A, B, K = _plant(seed)
    Ad, Bd = _zoh(A, B, H)
    x0, u0 = np.array([1.0, -0.5, 0.3]), np.array([0.2, -0.1])
    D = round(tau / H)
    line = ChannelLine(channel, 3, H, list(x0))
    ctrl = StampedController(A, B, K, T, tau, age_max, "compensated", u0)
    nominal = None if stamped else LTIPredictor(A, B, T, channel.delay, tau)
    outputs = []  # the controller's output at each step (held)
    xs, preds, ages, off = [x0], [], [], []
    x = x0
    for k in range(steps):
        y, stamp = line.step(list(x))
        if k % N == 0:
            x_hat = ctrl.predict(y, stamp)
            u = ctrl.propose(y, stamp)
            ctrl.commit(u, y, stamp)
            preds.append((k, x_hat))
            ages.append(k * H - stamp)
            if nominal is not None:  # what the controller assuming the delay r predicts
                hist = list(reversed([outputs[j] for j in range(0, k, N)]))[:nominal.L]
                hist += [u0] * (nominal.L - len(hist))
                off.append((k, nominal.predict(np.array(y), hist)))
        outputs.append(ctrl.held)
        applied = outputs[k - D] if k >= D else u0
        x = Ad @ x + Bd @ applied
        xs.append(x)
    return preds, np.array(xs), np.array(ages), off


@pytest.mark.parametrize("policy", ["in_order", "drop_stale"])
@pytest.mark.parametrize("tau", [0.2, 0.23])
def test_the_prediction_is_exact_under_jitter_and_loss(policy, tau):
    """Jitter up to 2.5 T (packets overtake each other), 30 % of the packets lost: the
    prediction is the plant's state tau ahead, at round-off, at every sampling instant;
    tau need not be a multiple of T here."""
    channel = Channel(delay=0.05, distribution="uniform", jitter=0.25,
                      loss_model="bernoulli", loss=0.3, policy=policy, seed=4)
    steps = 600
    preds, xs, ages, _ = _closed_loop(channel, tau, steps + 30)
    D = round(tau / H)
    scale = np.abs(xs).max()
    worst = max(np.abs(x_hat - xs[k + D]).max() for k, x_hat in preds if k + D <= steps)
    assert worst <= 1e-11 * scale, worst / scale
    assert ages.max() > 2 * T and len(np.unique(np.round(ages, 9))) > 5  # jitter and loss


def test_the_nominal_predictor_is_not_exact_there():
    """The same runs with the predictor that assumes the nominal age r: off by far more
    than round-off (so the test above can fail)."""
    channel = Channel(delay=0.05, distribution="uniform", jitter=0.25,
                      loss_model="bernoulli", loss=0.3, seed=4)
    _preds, xs, _, off = _closed_loop(channel, 0.2, 400, stamped=False)
    D = round(0.2 / H)
    worst = max(np.abs(x_hat - xs[k + D]).max() for k, x_hat in off if 100 <= k <= 400 - D)
    assert worst >= 1e-3 * np.abs(xs).max()


def test_a_constant_channel_gives_the_nominal_controller():
    """No jitter, no loss: once the samples are past the history (t_i >= r), the
    stamp-driven prediction is the paper's predictor's (Corollary 3.4), to round-off."""
    channel = Channel(delay=0.05)
    preds, xs, _, off = _closed_loop(channel, 0.2, 300, stamped=False)
    for (k, a), (_, b) in zip(preds, off):
        if k * H >= 0.05:
            assert np.abs(a - b).max() <= 1e-12 * np.abs(xs).max()


def test_a_sample_older_than_age_max_is_not_used():
    """age_max below the channel's delays: no sample is ever new enough, the controller
    carries its first estimate (x0 at t0) forward: still exact without disturbance."""
    channel = Channel(delay=0.3)
    preds, xs, _, _ = _closed_loop(channel, 0.2, 200, age_max=0.1)
    worst = max(np.abs(x_hat - xs[k + 20]).max() for k, x_hat in preds if k + 20 <= 200)
    assert worst <= 1e-11 * np.abs(xs).max()


def test_the_state_restores_the_run():
    A, B, K = _plant()
    a = StampedController(A, B, K, T, 0.2, 0.6, "compensated", [0.0, 0.0])
    rng = np.random.default_rng(1)
    samples = [(rng.normal(size=3), i * T - 0.05 * (1 + i % 3)) for i in range(30)]
    for y, s in samples[:12]:
        a.commit(a.propose(y, s), y, s)
    b = StampedController(A, B, K, T, 0.2, 0.6, "compensated", [0.0, 0.0])
    b.set_state(a.get_state())
    for y, s in samples[12:]:
        ua, ub = a.propose(y, s), b.propose(y, s)
        assert np.array_equal(ua, ub)
        a.commit(ua, y, s)
        b.commit(ub, y, s)


def test_uncompensated_is_the_feedback_on_the_sample():
    A, B, K = _plant()
    c = StampedController(A, B, K, T, 0.2, 0.6, "uncompensated", [0.0, 0.0])
    y = np.array([0.3, 0.1, -0.2])
    assert np.array_equal(c.propose(y, -0.1), K @ y)


@pytest.mark.parametrize("kwargs, message", [
    ({"T": 0.0}, "T = 0.0 is not allowed: must be a finite number > 0"),
    ({"tau": -0.1}, "tau = -0.1 is not allowed: must be a finite number >= 0.0"),
    ({"age_max": math.inf}, "age_max = inf is not allowed"),
    ({"mode": "x"}, "mode = 'x' is not allowed: must be one of compensated, uncompensated"),
    ({"age_max": 1e9}, "age_max + tau = 1000000000.2 is not allowed: must be at most"),
])
def test_bad_parameters_are_named(kwargs, message):
    A, B, K = _plant()
    args = {"T": T, "tau": 0.2, "age_max": 0.6, "mode": "compensated", "u0": [0.0, 0.0],
            **kwargs}
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("+", r"\+")):
        StampedController(A, B, K, **args)


def test_a_stamp_from_the_future_is_refused():
    A, B, K = _plant()
    c = StampedController(A, B, K, T, 0.2, 0.6, "compensated", [0.0, 0.0])
    with pytest.raises(ValueError, match=r"stamp = 0.5 at t = 0.0 is not allowed: must be a "
                                         r"finite time <= t"):
        c.propose([1.0, 0.0, 0.0], 0.5)


# -- the FMU (fmus/controller/delaycomp_controller_stamped.py) ----------------------------
@pytest.fixture(scope="module")
def stamped_fmu():
    from delaycomp.fmu.cache import fmu_path

    return fmu_path("stamped_controller", {"n": 3, "m": 2})


def _parameters():
    A, B, K = _plant()
    params = {"T": T, "tau": 0.2, "age_max": 0.6, "u0[1]": 0.2, "u0[2]": -0.1}
    for label, M in (("A", A), ("B", B), ("K", K)):
        params.update({f"{label}[{i + 1},{j + 1}]": float(M[i, j])
                       for i in range(M.shape[0]) for j in range(M.shape[1])})
    return params, A, B, K


def _drive_fmu(fmu, samples, state_at=None):
    from delaycomp.orchestrator.fmu import FmuComponent

    params, *_ = _parameters()
    comp = FmuComponent("c", fmu)
    comp.setup(0.0, 10.0, params)
    write = comp.writer(["y1", "y2", "y3", "stamp"])
    read = comp.reader(["u1", "u2"])
    write([*samples[0][0], samples[0][1]])
    comp.initialize()
    rows, state = [], None
    for k, (y, s) in enumerate(samples):
        write([*y, s])
        rows.append(read())
        if k == state_at:
            state = comp.get_state()
        for q in range(N):  # the base steps of one period
            comp.do_step(k * T + q * H, H)
    return comp, np.array(rows), state


def _samples(count: int):
    rng = np.random.default_rng(2)
    return [(list(rng.normal(size=3)), i * T - 0.01 * int(rng.integers(0, 25)))
            for i in range(count)]


def test_the_fmu_is_the_maths(stamped_fmu):
    """The controller's outputs at each instant (samples of varying age, some repeated
    stamps: lost ones) are the maths class's, the same doubles."""
    samples = _samples(40)
    samples[7] = (samples[6][0], samples[6][1])  # a lost sample: the last one shown again
    comp, got, _ = _drive_fmu(stamped_fmu, samples)
    comp.terminate()
    _, A, B, K = _parameters()
    ctrl = StampedController(A, B, K, T, 0.2, 0.6, "compensated", [0.2, -0.1])
    want = []
    for y, s in samples:
        u = ctrl.propose(y, s)
        ctrl.commit(u, y, s)
        want.append(u)
    assert np.array_equal(got, np.array(want))


def test_the_fmu_state_restores_the_run(stamped_fmu):
    from delaycomp.orchestrator.fmu import FmuComponent

    samples = _samples(30)
    comp, whole, state = _drive_fmu(stamped_fmu, samples, state_at=12)
    comp.terminate()
    params, *_ = _parameters()
    again = FmuComponent("again", stamped_fmu)
    again.setup(0.0, 10.0, params)
    again.initialize()
    again.set_state(state)
    write, read = again.writer(["y1", "y2", "y3", "stamp"]), again.reader(["u1", "u2"])
    for q in range(N):
        again.do_step(12 * T + q * H, H)
    rows = []
    for k in range(13, 30):
        y, s = samples[k]
        write([*y, s])
        rows.append(read())
        for q in range(N):
            again.do_step(k * T + q * H, H)
    again.terminate()
    assert np.array_equal(np.array(rows), whole[13:])


@pytest.mark.parametrize("mutate, message", [
    (lambda c: c.__setitem__("z", [1.0]), "hidden.ctrl.z = [1.0]: must be a list of 3 finite"),
    (lambda c: c.__setitem__("i", -2), "hidden.ctrl.i = -2: must be an integer >= 0"),
    (lambda c: c.__setitem__("stamp", 99.0), "hidden.ctrl.stamp = 99.0: must be a time before"),
    (lambda c: c.__setitem__("history", []), "hidden.ctrl.history = []: must be a list of"),
    (lambda c: c.__setitem__("z", None), "hidden.ctrl.z = None: must be null exactly before"),
])
def test_a_crafted_fmu_state_is_refused_naming_the_field(stamped_fmu, mutate, message):
    import json

    from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

    comp, _, state = _drive_fmu(stamped_fmu, _samples(10), state_at=5)
    comp.terminate()
    data = json.loads(state)
    mutate(data["hidden"]["ctrl"])
    params, *_ = _parameters()
    fresh = FmuComponent("crafted", stamped_fmu)
    fresh.setup(0.0, 10.0, params)
    fresh.initialize()
    with pytest.raises(FmuRefused) as info:
        fresh.set_state(json.dumps(data).encode())
    assert message in str(info.value), str(info.value)


def test_the_fmu_refuses_a_stamp_from_the_future(stamped_fmu):
    from fmpy.fmi1 import FMICallException

    from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

    params, *_ = _parameters()
    comp = FmuComponent("future", stamped_fmu)
    comp.setup(0.0, 10.0, params)
    comp.initialize()
    comp.writer(["y1", "y2", "y3", "stamp"])([1.0, 0.0, 0.0, 0.5])
    with pytest.raises((FmuRefused, FMICallException)):
        comp.do_step(0.0, H)
    assert "stamp = 0.5 at t = 0.0 is not allowed: must be a finite time <= t" in (
        comp.last_message or ""), comp.messages
