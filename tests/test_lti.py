"""The LTI maths against direct numerical solves and the paper's closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from delaycomp.maths.lti import (
    LTIPredictor,
    critical_delay,
    discretize,
    flow,
    lifted_loop,
    predict_by_integration,
    split_delay,
)
from delaycomp.maths.zoh import ZOHController

from .roundoff import EPS

# Direct ODE solves run at rtol = atol = 1e-12; on these O(1) problems over a few seconds
# their error is ~1e-10, so closed forms are compared to them at 1e-8.
ODE_TOL = 1e-12
VS_ODE = 1e-8
# Two exact formulas differ only by round-off of a few matrix products: 1e-10 leaves room
# for the growth of e^{A t} over windows of a few seconds.
EXACT = 1e-10


def random_system(seed: int, n: int, m: int):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    B = rng.normal(size=(n, m))
    return A, B, rng


def ode_solve(A, B, x0, segments):
    """Integrate x' = A x + B u over ``(duration, u)`` segments with solve_ivp."""
    x = np.array(x0, dtype=float)
    for duration, u in segments:
        if duration == 0:
            continue
        sol = solve_ivp(lambda t, z, u=u: A @ z + B @ u, (0.0, duration), x, method="DOP853",
                        rtol=ODE_TOL, atol=ODE_TOL)
        x = sol.y[:, -1]
    return x


@pytest.mark.parametrize("n,m", [(1, 1), (2, 1), (3, 2)], ids=["n1m1", "n2m1", "n3m2"])
def test_flow_matches_ode_solve(n, m):
    A, B, rng = random_system(n * 10 + m, n, m)
    x0, u = rng.normal(size=n), rng.normal(size=m)
    E, G = flow(A, B, 0.7)
    np.testing.assert_allclose(E @ x0 + G @ u, ode_solve(A, B, x0, [(0.7, u)]),
                               rtol=VS_ODE, atol=VS_ODE)


def test_flow_singular_A_is_exact():
    # chain of two integrators: x1(h) = x1 + h x2 + h^2/2 u, x2(h) = x2 + h u
    Ad, Bd = discretize([[0, 1], [0, 0]], [[0], [1]], 0.5)
    # expm (a Pade approximant, BLAS products) of O(1) entries: a few EPS
    np.testing.assert_allclose(Ad, [[1, 0.5], [0, 1]], rtol=0, atol=8 * EPS)
    np.testing.assert_allclose(Bd, [[0.125], [0.5]], rtol=0, atol=8 * EPS)


@pytest.mark.parametrize(
    "r,T,q,rt",
    [(0.3, 1.0, 0, 0.3), (0.3, 0.1, 3, 0.0), (1.0, 0.1, 10, 0.0), (0.0, 1.0, 0, 0.0),
     (2.5, 1.0, 2, 0.5), (0.7, 0.7, 1, 0.0)],
)
def test_split_delay_takes_integers_despite_round_off(r, T, q, rt):
    got_q, got_rt = split_delay(r, T)
    assert got_q == q
    # r - q T in floating point: round-off of the larger of r and q T
    assert got_rt == pytest.approx(rt, abs=4 * EPS * max(r, T))


# (seed, n, m, T, r, tau): q = [r/T] >= 2 and l >= 1 included, and r/T integer
CASES = [
    (1, 1, 1, 1.0, 0.3, 0.0),
    (2, 2, 1, 0.5, 1.2, 0.5),    # q = 2, l = 1
    (3, 3, 2, 0.4, 1.0, 0.8),    # q = 2, r~ = 0.2, l = 2
    (4, 2, 2, 0.3, 0.9, 0.3),    # r/T integer (r~ = 0)
    (5, 4, 1, 0.25, 0.0, 0.75),  # r = 0, l = 3
]


@pytest.mark.parametrize("seed,n,m,T,r,tau", CASES, ids=[f"case{c[0]}" for c in CASES])
def test_closed_form_equals_exact_integration_and_ode(seed, n, m, T, r, tau):
    A, B, rng = random_system(seed, n, m)
    pred = LTIPredictor(A, B, T, r, tau)
    y = rng.normal(size=n)
    past = [rng.normal(size=m) for _ in range(pred.L)]  # past[p-1] = u_{i-p}
    # window [t - r - tau, t), oldest first: u_{i-L} for r~, then u_{i-L+1} .. u_{i-1}
    segments = [(pred.r_tilde, past[-1])] + [(T, past[p - 1]) for p in range(pred.L - 1, 0, -1)]
    assert sum(d for d, _ in segments) == pytest.approx(r + tau, abs=1e-12)
    closed = pred.predict(y, past)
    np.testing.assert_allclose(closed, predict_by_integration(A, B, y, segments),
                               rtol=EXACT, atol=EXACT)
    np.testing.assert_allclose(closed, ode_solve(A, B, y, segments), rtol=VS_ODE, atol=VS_ODE)


def test_example_3_6_feedback_3_22_is_the_closed_form():
    """(3.22): u_i = -k e^r y_i - k (e^r - 1) u_{i-1} for x' = x + u, r < T."""
    k, r, T = 2.0, 0.3, 1.0
    ctrl = ZOHController([[1.0]], [[1.0]], [[-k]], T, r, 0.0, "compensated", [4.0])
    y = 1.0
    u0 = ctrl.propose([y])[0]
    assert u0 == pytest.approx(-k * math.exp(r) * y - k * (math.exp(r) - 1) * 4.0, rel=1e-14)
    ctrl.commit([u0])
    assert ctrl.propose([0.5])[0] == pytest.approx(
        -k * math.exp(r) * 0.5 - k * (math.exp(r) - 1) * u0, rel=1e-14)


def test_uncompensated_controller_is_K_y():
    ctrl = ZOHController([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.3, 0.0, "uncompensated", [4.0])
    assert ctrl.propose([0.75])[0] == -1.5


def simulate_sampled_loop(A, B, K, T, r, tau, mode, x0, u0, periods, sub=50):
    """Direct simulation with solve_ivp on a fine grid (independent of the lifted model)."""
    h = T / sub
    D, Lu = round(r / h), round(tau / T)
    ctrl = ZOHController(A, B, K, T, r, tau, mode, u0)
    xs = [np.array(x0, float)]
    held = []
    for i in range(periods):
        idx = i * sub - D
        y = xs[idx] if idx >= 0 else np.array(x0, float)
        u = ctrl.propose(y)
        ctrl.commit(u)
        held.append(u)
        applied = held[i - Lu] if i - Lu >= 0 else np.array(u0, float)
        for _ in range(sub):
            xs.append(ode_solve(A, B, xs[-1], [(h, applied)]))
    return np.array(xs), held


@pytest.mark.parametrize("mode", ["compensated", "uncompensated"])
def test_lifted_loop_matches_direct_simulation(mode):
    A, B = np.array([[0.2, 1.0], [-1.0, 0.1]]), np.array([[0.0], [1.0]])
    K = np.array([[-0.5, -1.0]])
    T, r, tau = 0.5, 0.6, 0.5
    loop = lifted_loop(A, B, K, T, r, tau, mode)
    sub = 10
    xs, held = simulate_sampled_loop(A, B, K, T, r, tau, mode, [1.0, -0.5], [0.3], periods=8,
                                     sub=sub)
    D = round(r / (T / sub))

    def X(i):  # lifted state (x(iT - r), u_{i-1}, .., u_{i-L}) from the trajectory
        return np.concatenate([xs[i * sub - D]] + [held[i - j] for j in range(1, loop.L + 1)])

    for i in range(loop.L + 2, 7):
        np.testing.assert_allclose(loop.M @ X(i), X(i + 1), rtol=VS_ODE, atol=VS_ODE)


def test_compensation_restores_the_delay_free_spectrum():
    """Compensated lifted loop = eig(Ad + Bd K) plus zeros (Corollary 3.4's hypothesis)."""
    A, B, _ = random_system(7, 3, 1)
    K = np.array([[-1.0, -2.0, -0.5]])
    Ad, Bd = discretize(A, B, 0.4)
    loop = lifted_loop(A, B, K, 0.4, 1.1, 0.8, "compensated")
    eig = np.sort_complex(np.linalg.eigvals(loop.M))
    expected = np.sort_complex(np.concatenate(
        [np.linalg.eigvals(Ad + Bd @ K), np.zeros(loop.M.shape[0] - 3)]))
    # zero eigenvalues of a nilpotent block are ill-conditioned: compare radii of the
    # non-zero ones and that the rest are small
    big = np.abs(expected) > 1e-6
    np.testing.assert_allclose(np.sort(np.abs(eig))[-big.sum():], np.sort(np.abs(expected[big])),
                               rtol=1e-8)
    assert loop.spectral_radius == pytest.approx(np.max(np.abs(expected)), rel=1e-8)


def test_critical_delay_of_example_3_6_in_paper_bracket():
    def rho(r):
        return lifted_loop([[1.0]], [[1.0]], [[-2.0]], 1.0, r, 0.0, "uncompensated").spectral_radius

    r_c = critical_delay(rho, r_max=5.0, step=0.01)
    assert 0.20 < r_c < 0.21  # the paper: r_c in (0.20, 0.21)
    assert rho(r_c - 1e-7) < 1.0 < rho(r_c + 1e-7)
    # the compensated loop is stable far beyond r_c (and for r >= T, l + q > 0)
    for r in (0.3, 0.9, 2.7):
        assert lifted_loop([[1.0]], [[1.0]], [[-2.0]], 1.0, r, 0.0, "compensated"
                           ).spectral_radius == pytest.approx(math.e - 2, rel=1e-10)


def test_sampled_period_bound_3_20():
    """(3.20): u = -k x under ZOH without delay is stable iff T < ln(1 + 2/(k-1))."""
    k = 2.0
    T_max = math.log(1 + 2 / (k - 1))
    for T, stable in ((0.99 * T_max, True), (1.01 * T_max, False)):
        rho = lifted_loop([[1.0]], [[1.0]], [[-k]], T, 0.0, 0.0, "uncompensated").spectral_radius
        assert (rho < 1) == stable
