"""Reference traces for Proposition 4.2 (unicycle, zero-order hold), computed without delaycomp.

Plant (4.4): ``x' = v(t - tau) cos(theta)``, ``y' = v(t - tau) sin(theta)``,
``theta' = omega(t - tau)``, ``tau = l T``. The controller emits ``(v_i, omega_i)`` at
``t_i = iT`` (``i >= 0``) and holds it on ``[iT, (i+1)T)``; the plant applies it on
``[iT + tau, (i+1)T + tau)``. Measurement ``(x, y, theta)(iT - r)``; a measurement with
``iT - r <= 0`` reads ``x0`` (plant state ``x0`` on ``[-r, 0]``); controller output
``(v, omega) = u0`` on ``[-r - tau, 0)``.

Prediction (4.12), evaluated literally in controller time: starting from the measurement,
integrate the unicycle over the window ``[iT - r - tau, iT)`` with the stored held outputs
(``u0`` for cells before 0). With a constant ``(v, omega)`` for a time ``s`` the unicycle
moves exactly as

    theta+ = theta + omega s,
    (X, Y)+ = (X, Y) + v s sinc(omega s / 2) (cos, sin)(theta + omega s / 2),
    sinc(z) = sin(z) / z,

so the prediction and the plant are closed-form (checked against ``solve_ivp`` at
rtol = atol = 1e-12 in ``check()``: agreement to ~1e-13).

Law: the CORRECTED zero-order-hold law for ``(v, omega)`` of ../shared/ERRATA.md,
item 2 ("A zero-order-hold law for (v, omega) itself"), in the coordinates (4.2) of the
predicted state ``x1 = X cos + Y sin``, ``x2 = X sin - Y cos``, ``x3 = Theta``:

- if ``|x1| <= eps`` and ``|x2| <= eps``: ``(v, omega) = (0, -x3 / T)``;
- elif ``|x2| <= eps``: ``(v, omega) = (-x1 / T, 0)``;
- else ``a = min(sqrt|x2|, pi/2)``, ``b = -a (x1 sin a + x2 cos a) / (1 - cos a)``,
  ``(v, omega) = (b / T, a / T)`` (``1 - cos a`` is evaluated as ``2 sin(a/2)^2``).

``eps = EPS * max(1, |x1|, |x2|, |x3|)`` with ``EPS = 1e-10`` (scaled classification; exact
``== 0`` tests fail in floating point, see the errata's implementation points). It is
dead-beat in 3T without delay; the printed (4.9)-(4.11) with ``(v, omega)`` held is not
(``demo_printed_law()``).

The traces are exact up to round-off (no ODE solver is involved); ``RelTol`` in the
``.opt`` files is 1e-09 as for the other closed-form references. Run
``python reference/proposition_4_2.py`` from the repository root to regenerate
``reference/proposition-4.2/``; ``--check`` runs the checks and demonstrations.
"""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path

import numpy as np
from reftools import main, write_trace

OUT = Path(__file__).resolve().parent / "proposition-4.2"

EPS = 1e-10

#: name -> (T, r, tau, N, x0 = (x, y, theta), u0 = (v, omega), stop time)
CASES = {
    "default": dict(T=1.0, r=0.5, tau=1.0, N=100, x0=(1.0, 1.0, 0.5), u0=(0.0, 0.0),
                    stop=10.0),
    "nodelay_r": dict(T=1.0, r=0.5, tau=0.0, N=100, x0=(-2.0, 0.5, 2.5), u0=(0.0, 0.0),
                      stop=10.0),
}


# --------------------------------------------------------------------------- flow
def sinc(z):
    """``sin(z) / z`` (1 at 0)."""
    return 1.0 if z == 0.0 else math.sin(z) / z


def flow(w, u, s):
    """Unicycle state after time ``s`` under constant ``u = (v, omega)``."""
    X, Y, th = w
    v, om = u
    half = om * s / 2
    d = v * s * sinc(half)
    return (X + d * math.cos(th + half), Y + d * math.sin(th + half), th + om * s)


def to_nhi(w):
    """(4.2): unicycle state -> coordinates of (1.4)."""
    X, Y, th = w
    c, s = math.cos(th), math.sin(th)
    return X * c + Y * s, X * s - Y * c, th


# --------------------------------------------------------------------------- laws
def law_corrected(w, T, eps_rel=EPS):
    """ERRATA item 2: zero-order-hold law for (v, omega), dead-beat in 3T."""
    x1, x2, x3 = to_nhi(w)
    eps = eps_rel * max(1.0, abs(x1), abs(x2), abs(x3))
    if abs(x1) <= eps and abs(x2) <= eps:
        return 0.0, -x3 / T
    if abs(x2) <= eps:
        return -x1 / T, 0.0
    a = min(math.sqrt(abs(x2)), math.pi / 2)
    b = -a * (x1 * math.sin(a) + x2 * math.cos(a)) / (2 * math.sin(a / 2) ** 2)
    return b / T, a / T


def law_printed(w, T, eps_rel=EPS):
    """(4.9)-(4.11) as printed, (v, omega) held; sets classified C3, then C2, then C1."""
    x1, x2, x3 = to_nhi(w)
    sc = max(1.0, abs(x1), abs(x2), abs(x3))
    eps = eps_rel * sc
    if abs(2 * x2 - x1 * x3) <= eps * sc:                      # C3
        k1, k2 = -x1 / T, -x3 / T
    elif abs(x2) <= eps and abs(x1 * x3) > eps * sc:           # C2
        d = T * (x1 * x1 + x3 * x3)
        k1, k2 = -x1 * x3 * x3 / d, x3 * x1 * x1 / d
    else:                                                      # C1
        sq = math.sqrt(abs(x2))
        k1, k2 = -2 / T * math.copysign(sq, x2) - 2 / T * x1, sq / T
    return k1 + x2 * k2, k2                                    # (4.11), (4.10)


# --------------------------------------------------------------------------- closed loop
def _frac(x) -> Fraction:
    return Fraction(str(x))


def simulate(T, r, tau, x0, u0, periods, law=law_corrected):
    """Plant states p[j] = p(jT), j = 0..periods+1, outputs u[i], predictions pred[i]."""
    Tf, rf, tf = _frac(T), _frac(r), _frac(tau)
    lag = tf / Tf
    assert lag.denominator == 1, "tau must be an integer multiple of T"
    lag = int(lag)
    q = int(rf // Tf)
    rt = float(rf - q * Tf)          # r~ in [0, T)
    x0 = tuple(float(v) for v in x0)
    u0 = (float(u0[0]), float(u0[1]))
    us: list = []

    def u_hist(m):                    # controller output held on [mT, (m+1)T)
        return u0 if m < 0 else us[m]

    p = [x0]
    preds = []
    for i in range(periods + 1):
        # measurement x(iT - r), iT - r = (i - q) T - r~
        if i * Tf - rf <= 0:
            m = x0
        elif rt == 0.0:
            m = p[i - q]
        else:
            m = flow(p[i - q - 1], u_hist(i - q - 1 - lag), T - rt)
        # (4.12): window [iT - r - tau, iT) in controller time = [(i-lag-q)T - r~, iT)
        w = m
        if rt > 0.0:
            w = flow(w, u_hist(i - lag - q - 1), rt)
        for c in range(i - lag - q, i):
            w = flow(w, u_hist(c), T)
        preds.append(w)
        us.append(law(w, T))
        p.append(flow(p[i], u_hist(i - lag), T))   # plant applies u_{i-lag} on [iT, (i+1)T)
    return p, us, preds, lag


def trace(T, r, tau, N, x0, u0, stop, law=law_corrected):
    """Rows ``(t, x, y, theta, v, omega)`` at ``t_k = k T / N``, ``k = 0 .. stop N / T``."""
    periods = round(stop / T)
    p, us, _, lag = simulate(T, r, tau, x0, u0, periods, law)
    rows = []
    for k in range(periods * N + 1):
        i, m = divmod(k, N)
        s = m * T / N
        up = tuple(map(float, u0)) if i - lag < 0 else us[i - lag]
        w = p[i] if m == 0 else flow(p[i], up, s)
        rows.append((i * T + s, w[0], w[1], w[2], us[i][0], us[i][1]))
    return rows


def write(name: str, case: dict) -> None:
    """Write case ``name``'s trace and settings files (``reftools.write_trace``)."""
    write_trace(OUT, name, ("time", "plant.x", "plant.y", "plant.theta", "controller.v",
                            "controller.omega"), trace(**case), case["stop"],
                case["T"] / case["N"], 1e-09, positive_zero=True)


# --------------------------------------------------------------------------- checks
def check_flow(n=200, seed=1):
    """The sinc flow against solve_ivp (rtol = atol = 1e-12)."""
    from scipy.integrate import solve_ivp
    rng = np.random.default_rng(seed)
    err = 0.0
    for j in range(n):
        w = rng.uniform(-3, 3, 3)
        u = (rng.uniform(-3, 3), 0.0 if j % 10 == 0 else rng.uniform(-3, 3))
        s = rng.uniform(0, 2)
        sol = solve_ivp(lambda t, y, u=u: [u[0] * math.cos(y[2]), u[0] * math.sin(y[2]), u[1]],
                        (0, s), w, method="DOP853", rtol=1e-12, atol=1e-12)
        err = max(err, float(np.max(np.abs(sol.y[:, -1] - np.array(flow(w, u, s))))))
    print(f"sinc flow vs solve_ivp: max abs diff {err:.1e} over {n} random (state, input, s)")


def dead_beat_time(rows, thr=1e-9):
    """First output time from which |state| (Euclidean) stays below thr, and the residual."""
    arr = np.array(rows)
    nrm = np.linalg.norm(arr[:, 1:4], axis=1)
    above = np.nonzero(nrm >= thr)[0]
    if len(above) == 0:
        return 0.0, float(np.max(nrm)), nrm
    if above[-1] + 1 >= len(arr):
        return None, math.nan, nrm
    j = above[-1] + 1
    return float(arr[j, 0]), float(np.max(nrm[j:])), nrm


def check_plant_ode(name):
    """Re-integrate the plant of a written trace with solve_ivp, cell by cell."""
    from scipy.integrate import solve_ivp
    case = CASES[name]
    T, N = case["T"], case["N"]
    rows = np.array(trace(**case))
    _, us, _, lag = simulate(case["T"], case["r"], case["tau"], case["x0"], case["u0"],
                             round(case["stop"] / T))
    w = np.array(case["x0"], float)
    err = 0.0
    for i in range(round(case["stop"] / T)):
        v, om = tuple(map(float, case["u0"])) if i - lag < 0 else us[i - lag]
        ts = np.arange(N + 1) * T / N
        sol = solve_ivp(lambda t, y, v=v, om=om: [v * math.cos(y[2]), v * math.sin(y[2]), om],
                        (0, T), w, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=ts)
        err = max(err, float(np.max(np.abs(sol.y.T - rows[i * N:(i + 1) * N + 1, 1:4]))))
        w = sol.y[:, -1]
    return err


def check():
    """Print the checks: the sinc flow against a direct solve, each case's dead-beat time, the
    plant re-integrated."""
    check_flow()
    for name, case in CASES.items():
        rows = trace(**case)
        t_db, res, nrm = dead_beat_time(rows)
        p, _, preds, lag = simulate(case["T"], case["r"], case["tau"], case["x0"],
                                    case["u0"], round(case["stop"] / case["T"]))
        perr = max(max(abs(a - b) for a, b in zip(preds[i], p[i + lag]))
                   for i in range(len(preds)) if i + lag < len(p))
        print(f"{name}: state below 1e-9 from t = {t_db} (max |state| after: {res:.1e}); "
              f"|state| at t = 1, 2, 3, 4, 5: "
              + ", ".join(f"{nrm[int(j * case['N'])]:.2e}" for j in range(1, 6))
              + f"; max |prediction(iT) - x(iT + tau)| = {perr:.1e}; plant re-integrated by "
              f"solve_ivp (1e-12) differs by {check_plant_ode(name):.1e}")
        # an initial history that is not a solution: u0 != 0 with constant x0
        case2 = dict(case, u0=(0.3, -0.2))
        t2, res2, _ = dead_beat_time(trace(**case2))
        print(f"{name} with u0 = (0.3, -0.2) (inconsistent history): below 1e-9 from t = {t2} "
              f"(max after: {res2:.1e})")
    demo_printed_law()
    demo_dead_beat_no_delay()


def demo_printed_law():
    """The printed (4.9)-(4.11) with (v, omega) held is not dead-beat (default case)."""
    case = CASES["default"]
    for stop in (10.0, 50.0):
        rows = trace(**dict(case, stop=stop), law=law_printed)
        arr = np.array(rows)
        print(f"printed law, default case: |state(t = {stop:g})| = "
              f"{np.linalg.norm(arr[-1, 1:4]):.3e}; max |state| on [5, {stop:g}] = "
              f"{np.max(np.linalg.norm(arr[arr[:, 0] >= 5, 1:4], axis=1)):.3e}")


def demo_dead_beat_no_delay(n=100, seed=7, T=1.0):
    """Corrected law, no delay: x((i+1)T) = flow(x(iT), law(x(iT)), T); worst |x(3T)|."""
    rng = np.random.default_rng(seed)
    worst, worst_printed = 0.0, 0.0
    for _ in range(n):
        d = rng.normal(size=3)
        w = tuple(d / np.linalg.norm(d) * rng.uniform(0.1, 10.0))
        x = w
        for _ in range(3):
            x = flow(x, law_corrected(x, T), T)
        worst = max(worst, float(np.max(np.abs(x))))
        y = w
        for _ in range(3):
            y = flow(y, law_printed(y, T), T)
        worst_printed = max(worst_printed, float(np.max(np.abs(y))))
    print(f"corrected law, no delay, {n} random x0 (|x0| in [0.1, 10]): worst max|x(3T)| = "
          f"{worst:.1e}; printed law with (v, omega) held: worst max|x(3T)| = {worst_printed:.2e}")


if __name__ == "__main__":
    main(OUT, CASES, write, {"--check": check})
