"""Reference traces for Example 2.4 (strict-feedforward plant, continuously adjusted input,
Theorem 2.1), computed without the delaycomp package.

Plant (2.15): ``x1' = x2 + x3^2``, ``x2' = x3 + x3 u(t - tau)``, ``x3' = u(t - tau)``.
Measurement ``y_i = x(t_i - r)`` at ``t_i = iT``. Controller (2.5)-(2.6), i.e. (2.19)-(2.20):
between sampling instants ``z' = f(z, u(t))`` with ``u(t) = k(z(t))`` (the ideal continuous
law; k is time-invariant so ``k(t + tau, z) = k(z)``); at ``t_i``, ``i >= 1`` (not at 0),
``z(t_i) = Phi(y_i, u on [t_i - r - tau, t_i))``; ``z(0) = z0``. Initial histories
``x = x0`` on ``[-r, 0]`` and ``u = u0`` on ``[-r - tau, 0)``: a measurement with
``t_i - r <= 0`` reads ``x0``, and the plant input is ``u0`` for ``t < tau``.

Feedback: (2.18) with the correction of ERRATA item 1 (``-(1/8) x3^3`` in the bracket), i.e.
``k(x) = -x1 - 3 x2 - 3/8 x2^2 + 3/4 x3 (-4 - x1 - 2 x2 + x3/2 + x2 x3/2 + 5/8 x3^2
- 1/8 x3^3 - 3/8 (x2 - x3^2/2)^2)``; ``--check`` verifies that it equals the errata's
integrator-forwarding form at random points.

Method (method of steps, no interpolation): one ``solve_ivp`` (DOP853, rtol = atol = 1e-12)
integrates the 9-dimensional state ``(x, w, z)``, where ``w(t) = z(t - tau)`` is a delayed copy
of the controller (``w' = f(w, k(w))``, the plant input is ``k(w)`` for ``t >= tau`` and ``u0``
before). Integration is restarted at every base step ``t_k``, at every ``t_i`` (``z`` reset),
every ``t_j + tau`` (``w`` set to the reset value ``z(t_j)``, where the plant input jumps),
every ``t_i - r`` (measurement recorded) and every ``t_i - r - tau`` (``z`` recorded, the
start of the predictor window). ``Phi`` (definition before (2.1)) is a direct ``solve_ivp`` of
the plant from ``x(t_i - r) = y_i`` over the window, driven by ``u0`` for ``sigma < 0`` and by
the stored controller segments (again as a delayed copy started from the recorded ``z``
values), so the input history is exactly the one applied. ``--check`` also compares
(2.16)-(2.17) with a direct solve for a polynomial history, checks the prediction
(``z(t) = x(t + tau)`` for ``t >= T``) and compares the trace with a run at 1e-13 and with the
delay-free closed loop ``x' = f(x, k(x))`` from ``x(T + tau)``.

Tolerance: rtol = atol = 1e-12 (the ``RelTol`` of the ``.opt`` files). Achieved accuracy
(``--check``): the run at 1e-13 differs by at most 3e-13 (``default``) and 2.9e-12 (``sparse``,
in ``u``), and the 1e-13 run agrees with a 1e-14 run to 5e-13; later resets jump by <= 6e-13
(the first, at ``T``, by 0.35, as expected from ``z0``).

Run ``python reference/example_2_4.py`` from the repository root to regenerate
``reference/example-2.4/``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from reftools import main, solve, write_trace
from scipy.integrate import solve_ivp

OUT = Path(__file__).resolve().parent / "example-2.4"
TOL = 1e-12

#: name -> period T, measurement delay r, input delay tau, initial state x0 (constant on
#: [-r, 0]), initial input u0 (constant on [-r - tau, 0)), controller state z0, base steps
#: per period N, stop time
CASES = {
    "default": dict(T=0.5, r=0.3, tau=0.7, x0=(1.0, -1.0, 0.5), u0=0.0, z0=(1.0, -1.0, 0.5),
                    N=100, stop=30.0),
    "sparse": dict(T=2.0, r=0.3, tau=0.7, x0=(1.0, -1.0, 0.5), u0=0.0, z0=(1.0, -1.0, 0.5),
                   N=100, stop=30.0),
}


def f(x, v):
    """(2.15) with input value ``v``."""
    return np.array([x[1] + x[2] * x[2], x[2] + x[2] * v, v])


def k(x):
    """(2.18) with ERRATA item 1 (-(1/8) x3^3)."""
    x1, x2, x3 = x
    return (-x1 - 3 * x2 - 3 / 8 * x2 ** 2
            + 3 / 4 * x3 * (-4 - x1 - 2 * x2 + x3 / 2 + x2 * x3 / 2 + 5 / 8 * x3 ** 2
                            - 1 / 8 * x3 ** 3 - 3 / 8 * (x2 - x3 ** 2 / 2) ** 2))


def k_forwarding(x):
    """The errata's integrator-forwarding form (used only by ``--check``)."""
    x1, x2, x3 = x
    xi2 = x2 - x3 ** 2 / 2
    eta2 = xi2 + x3
    eta1 = x1 + 2 * eta2 - x3 + 3 / 4 * x3 ** 2 - 3 / 4 * x3 * eta2 + 3 / 8 * eta2 ** 2
    return -(eta2 + x3) - (1 + 3 * x3 / 4) * eta1


def _solve(rhs, y0, duration, tol):
    return solve(rhs, y0, 0.0, duration, tol)


def _closed(t, y):   # a controller copy: y' = f(y, k(y))
    return f(y, k(y))


def _plant_and_copy(t, s):   # (x, w): x' = f(x, k(w)), w' = f(w, k(w))
    v = k(s[3:6])
    return np.concatenate([f(s[0:3], v), f(s[3:6], v)])


def simulate(T, r, tau, x0, u0, z0, N, stop, tol=TOL):
    """Closed loop by the method of steps. Returns the rows and a dict of diagnostics."""
    x0 = np.array(x0, dtype=float)
    z0 = np.array(z0, dtype=float)
    periods = round(stop / T)
    kmax = periods * N
    eps = 1e-9 * T / N
    # events: (time, order, kind, index); order fixes what happens first at a common time
    events = [((kk // N) * T + (kk % N) * T / N, 4, "grid", kk) for kk in range(kmax + 1)]
    for i in range(1, periods + 1):
        events.append((i * T, 1, "reset", i))
        if i * T - r > 0:
            events.append((i * T - r, 0, "meas", i))
        if i * T - r - tau > 0:
            events.append((i * T - r - tau, 3, "zrec", i))
    for j in range(periods + 1):
        if j * T + tau <= stop + eps:
            events.append((j * T + tau, 2, "wset", j))
    events.sort(key=lambda e: (e[0], e[1]))
    # merge times closer than eps onto one time (the grid time when there is one)
    groups = []
    for ev in events:
        if groups and ev[0] - groups[-1][0][0] < eps:
            groups[-1].append(ev)
        else:
            groups.append([ev])
    groups = [(next((e[0] for e in g if e[2] == "grid"), g[0][0]),
               sorted(g, key=lambda e: e[1])) for g in groups]

    z_reset = {0: z0.copy()}   # z(t_j) after the reset
    z_pre = {}                 # z(t_j^-) before it
    y_meas = {}
    z_rec = {}                 # z(t_i - r - tau)

    def phi(i):
        """State at t_i + tau of the plant started at x(t_i - r) = y_i, driven by u(s - tau)."""
        ti = i * T
        y = y_meas.get(i, x0)
        a = ti - r - tau                      # window start in controller time sigma
        if a < -eps:                          # the initial input history
            y = _solve(lambda t, s: f(s, u0), y, min(-a, r + tau), tol)
            a = 0.0
        # controller segments [t_j, t_{j+1}) intersecting [a, t_i)
        j = int(np.floor(a / T + 1e-9))
        if abs(a - j * T) < eps or abs(a - (j + 1) * T) < eps:
            j = round(a / T)
            a = j * T
            w = z_reset[j]
        else:
            w = z_rec[i]
        s = np.concatenate([y, w])
        while a < ti - eps:
            b = min((j + 1) * T, ti)
            s = _solve(_plant_and_copy, s, b - a, tol)
            j += 1
            a = b
            if a < ti - eps:
                s[3:6] = z_reset[j]
        return s[0:3]

    rows = []
    jumps = []
    x = x0.copy()
    w = z0.copy()      # unused before tau
    z = z0.copy()
    w_on = False
    for g, (t, evs) in enumerate(groups):
        for _, _, kind, idx in evs:
            if kind == "meas":
                y_meas[idx] = x.copy()
            elif kind == "reset":
                z_pre[idx] = z.copy()
                z = phi(idx)
                z_reset[idx] = z.copy()
                jumps.append((idx, float(np.abs(z - z_pre[idx]).max())))
            elif kind == "wset":
                w = z_reset[idx].copy()
                w_on = True
            elif kind == "zrec":
                z_rec[idx] = z.copy()
            elif kind == "grid":
                rows.append((t, float(x[0]), float(x[1]), float(x[2]), float(k(z))))
        if g + 1 == len(groups):
            break
        dt = groups[g + 1][0] - t
        if w_on:
            s = _solve(lambda t_, s_: np.concatenate(
                [_plant_and_copy(t_, s_[0:6]), _closed(t_, s_[6:9])]),
                np.concatenate([x, w, z]), dt, tol)
            x, w, z = s[0:3], s[3:6], s[6:9]
        else:
            s = _solve(lambda t_, s_: np.concatenate([f(s_[0:3], u0), _closed(t_, s_[3:6])]),
                       np.concatenate([x, z]), dt, tol)
            x, z = s[0:3], s[3:6]
    return rows, dict(jumps=jumps, z_reset=z_reset)


def trace(T, r, tau, x0, u0, z0, N, stop, tol=TOL):
    """Rows ``(t, x1, x2, x3, u)`` at ``t_k = (k // N) T + (k % N) T / N``."""
    return simulate(T, r, tau, x0, u0, z0, N, stop, tol)[0]


def write(name: str, case: dict) -> None:
    """Write case ``name``'s trace and settings files (``reftools.write_trace``)."""
    write_trace(OUT, name, ("time", "plant.x1", "plant.x2", "plant.x3", "controller.u"),
                trace(**case), case["stop"], case["T"] / case["N"], TOL)


# ----------------------------------------------------------------------------- checks


def phi_formula(x, c, r, tau):
    """(2.16)-(2.17) for the polynomial history u(s) = sum c_j s^j on [-r - tau, 0)."""
    from numpy.polynomial import Polynomial as Pn
    a = -r - tau
    h = r + tau
    u = Pn(c)
    U = u.integ(lbnd=a)                     # int_a^s u
    one_u_U = (1 + u) * U
    G = one_u_U.integ(lbnd=a)               # int_a^w (1 + u) U
    x1, x2, x3 = x
    iu = U(0.0)
    phi3 = x3 + iu
    phi2 = x2 + h * x3 + x3 * iu + G(0.0)
    phi1 = (x1 + h * x2 + h * x3 ** 2 + 0.5 * h ** 2 * x3 + 3 * x3 * U.integ(lbnd=a)(0.0)
            + G.integ(lbnd=a)(0.0) + (U * U).integ(lbnd=a)(0.0))
    return np.array([phi1, phi2, phi3])


def check():
    """Print the checks: (2.18) against the forwarding form, the trace against dense outputs and
    against the delay-free loop."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(-5, 5, size=(2000, 3))
    d = max(abs(k(p) - k_forwarding(p)) / (1 + abs(k(p))) for p in pts)
    print(f"k (2.18 corrected) vs forwarding form: max rel diff {d:.1e}")
    printed = lambda x: k(x) - 3 / 32 * x[2] ** 4  # noqa: E731  (2.18 as printed)
    print("  printed (2.18) differs from corrected by -(3/32) x3^4 at x3=2:",
          printed((0, 0, 2.0)) - k((0, 0, 2.0)))
    for r, tau in [(0.3, 0.7), (0.0, 1.3), (0.8, 0.0)]:
        for c in [(0.3, -1.2, 0.7), (-2.0, 0.5, 1.5, -0.4)]:
            x = np.array([0.4, -1.1, 0.9])
            up = np.polynomial.Polynomial(c)
            direct = solve_ivp(lambda t, s, up=up, tau=tau: f(s, up(t - tau)), (-r, tau), x,
                               method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
            print(f"(2.16)-(2.17) vs direct solve, r={r} tau={tau} c={c}: "
                  f"{np.abs(phi_formula(x, c, r, tau) - direct).max():.1e}")
    for name, case in CASES.items():
        rows, diag = simulate(**case)
        ref = np.array(rows)
        fine = np.array(simulate(**case, tol=1e-13)[0])
        T, N, tau = case["T"], case["N"], case["tau"]
        err = np.abs(fine - ref).max(axis=0)
        print(f"{name}: tol 1e-12 vs 1e-13: max |diff| per column {err.tolist()}")
        print(f"{name}: reset jumps |z(t_i) - z(t_i^-)|: first {diag['jumps'][0][1]:.3e}, "
              f"later max {max(j for _, j in diag['jumps'][1:]):.1e}")
        # prediction: z(t) = x(t + tau) for t >= T, compared on the grid via u = k(z)
        shift = round(tau / (T / N))
        k1 = N
        xs = ref[:, 1:4]
        us = ref[:, 4]
        uk = np.array([k(x) for x in xs[k1 + shift:]])
        print(f"{name}: max |u(t) - k(x(t + tau))| for t >= T: "
              f"{np.abs(us[k1:len(us) - shift] - uk).max():.1e}")
        # before the first reset, by dense outputs instead of the delayed copy: xi is the
        # delay-free closed loop from z0, the plant gets u0 on [0, tau), k(xi(t - tau)) after
        h = T / N
        xi = solve_ivp(_closed, (0, T), np.array(case["z0"]), method="DOP853", rtol=1e-13,
                       atol=1e-13, dense_output=True)
        xa = solve_ivp(lambda t, s, u0=case["u0"]: f(s, u0), (0, tau), np.array(case["x0"]),
                       method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
        ks = np.arange(shift, N + shift + 1)
        xb = solve_ivp(lambda t, s, xi=xi, tau=tau: f(s, k(xi.sol(t - tau))), (tau, T + tau), xa,
                       method="DOP853", rtol=1e-13, atol=1e-13, t_eval=ks * h)
        print(f"{name}: [0, T + tau] by dense outputs: max |x diff| "
              f"{np.abs(xb.y.T - xs[ks]).max():.1e}, max |u diff| on [0, T) "
              f"{max(abs(k(xi.sol(ref[j, 0])) - us[j]) for j in range(N)):.1e}")
        # after T + tau the plant is the delay-free closed loop
        k2 = k1 + shift
        t2 = ref[k2, 0]
        sol = solve_ivp(_closed, (t2, ref[-1, 0]), xs[k2], method="DOP853", rtol=1e-13,
                        atol=1e-13, t_eval=ref[k2:, 0], dense_output=False)
        print(f"{name}: vs delay-free closed loop from x(T + tau): "
              f"{np.abs(sol.y.T - xs[k2:]).max():.1e}")
        nrm = np.linalg.norm(xs, axis=1)
        print(f"{name}: |x| at t = 10, 20, 30: {nrm[round(10 / T * N)]:.3e}, "
              f"{nrm[round(20 / T * N)]:.3e}, {nrm[-1]:.3e}; max |x| {nrm.max():.3f}, "
              f"max |u| {np.abs(us).max():.3f}")


if __name__ == "__main__":
    main(OUT, CASES, write, {"--check": check})
