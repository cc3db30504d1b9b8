"""Reference traces for Corollary 4.1 (unicycle, continuous input), computed without delaycomp.

Plant (4.4): ``x' = v(t - tau) cos(theta)``, ``y' = v(t - tau) sin(theta)``,
``theta' = omega(t - tau)``; measurements ``(x, y, theta)(iT - r)`` at ``t_i = iT``.
Initial data: plant state ``x0`` on ``[-r, 0]`` (a measurement with ``iT - r <= 0`` reads
``x0``), controller output ``(v, omega) = u0`` on ``[-r - tau, 0)``, controller state
``z(0) = x0`` (project convention for ``z0``).

Controller (Theorem 2.1 / Corollary 4.1): between sampling instants ``z`` follows (4.6)
driven by the controller's own output ``(v, omega)(t)`` = (4.8), the nominal law evaluated
at ``t + tau`` in the coordinates (4.2):

    x1 = zx cos(zth) + zy sin(zth),  x2 = zx sin(zth) - zy cos(zth),  x3 = zth,
    omega = k2(t + tau, x1, x2, x3),  v = k1(t + tau, x1, x2, x3) + x2 omega.

At ``t_i = iT``, ``i >= 1`` (not at 0), ``z`` is reset by (4.7): the predictor (4.5)
applied to the measurement and the stored output history on ``[iT - r - tau, iT)``. The
input is the ideal continuous law (not sampled).

Nominal law k (the smooth time-periodic stabilizer of (1.4) required by Corollary 4.1),
from J.-B. Pomet, "Explicit design of time-varying stabilizing control laws for a class of
controllable systems without drift", Systems & Control Letters 18 (1992) 147-158: his
construction ``u = h(t, x) - (L_f1 V, L_f2 V)`` with the periodic drift
``h = (x2 sin t, 0)``, whose flow is 2 pi-periodic, applied to (1.4) itself
(x1' = u1, x2' = x1 u2, x3' = u2; no relabelling needed). This is the 3-state example
usually quoted from that paper; its text was not retrievable here, so the formula was
re-derived and is verified below rather than copied:

    e  = x1 + x2 cos t
    k1 = x2 sin t - e
    k2 = -(e x1 cos t + x1 x2 + x3)

with ``V = ((x1 + x2 cos t)^2 + x2^2 + x3^2) / 2`` and ``V' = -e^2 - k2^2 <= 0``
(``pomet_lyapunov_check``); ``V' = 0`` on a solution forces ``x = 0`` (periodic LaSalle),
so the origin is UGAS. ``verify_law()`` checks it numerically (delay-free closed loop,
20 random states, 200 s): convergence is polynomial, ``|x| ~ 1.43 / sqrt(t)``.

Method: method of steps with ``scipy.integrate.solve_ivp`` (DOP853, rtol = atol = 1e-12)
on an augmented state, split at every jump of ``(v, omega)(t)`` or ``(v, omega)(t - tau)``
(``iT``, ``iT + tau``), at the measurement times ``iT - r``, at the window starts
``iT - r - tau``, and at every output time ``k T / N`` (so every reported value is a step
end point, not an interpolant). The augmented state holds

- ``z``: the controller state, ``z' = f(z, K(t + tau, z))``;
- ``zd = z(t - tau)``: the same ODE shifted by ``tau`` (``zd' = f(zd, K(t, zd))``, set to
  the post-reset ``z(iT)`` at ``iT + tau``), which gives the applied input
  ``(v, omega)(t - tau) = K(t, zd(t))`` without any interpolation;
- ``p``: the plant, driven by ``u0`` on ``[0, tau)`` and by ``K(t, zd)`` afterwards;
- one predictor accumulator ``(A, C, S)`` per pending reset ``i``, integrated over the
  window ``s in [iT - r - tau, iT)``: ``A' = omega(s)``, ``C' = v(s) cos A``,
  ``S' = v(s) sin A``. Then (4.7) is, with the measurement ``(mx, my, mth)``:
  ``z = (mx + C cos mth - S sin mth, my + C sin mth + S cos mth, mth + A)``.

All breakpoints are computed in exact rational arithmetic (``fractions.Fraction`` of the
decimal parameters). Accuracy (``python reference/corollary_4_1.py --check``): halving the
tolerance changes nothing (the 0.005 s segments are single steps), so the written trace is
compared with DOP853 at ``max_step = T/(8N)`` and with Radau at rtol = atol = 1e-12: both
agree to < 4e-14 in every column over 0..100 s. The prediction is exact from the first
reset (here the initial data are consistent: ``u0 = 0`` and constant ``x0``), so
``z(t) = p(t + tau)`` holds to 2.4e-15 and every reset jump is < 1.5e-15; the map
(4.2)-(4.3)-(4.8) is checked against (1.4) under ``k`` directly (2e-11, rtol 1e-12).
Run ``python reference/corollary_4_1.py`` from the repository root to regenerate
``reference/corollary-4.1/``; ``--check`` and ``--verify-law`` run the checks.
"""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path

import numpy as np
from reftools import main, solve, write_trace
from scipy.integrate import solve_ivp

OUT = Path(__file__).resolve().parent / "corollary-4.1"

RTOL = 1e-12
ATOL = 1e-12

#: name -> (T, r, tau, N, x0 = (x, y, theta), u0 = (v, omega), stop time)
CASES = {
    "default": dict(T=0.5, r=0.2, tau=0.3, N=100, x0=(1.0, 1.0, 0.5), u0=(0.0, 0.0),
                    stop=100.0),
}


# --------------------------------------------------------------------------- the law
def k_pomet(t, x1, x2, x3):
    """Pomet (1992) smooth time-periodic stabilizer of (1.4): returns (u1, u2)."""
    c = math.cos(t)
    e = x1 + x2 * c
    return x2 * math.sin(t) - e, -(e * x1 * c + x1 * x2 + x3)


def lyapunov(t, x1, x2, x3):
    """Pomet's Lyapunov function for k_pomet."""
    return 0.5 * ((x1 + x2 * math.cos(t)) ** 2 + x2 ** 2 + x3 ** 2)


def pomet_lyapunov_check(t, x1, x2, x3):
    """dV/dt along (1.4) with u = k_pomet, and the claimed value -e^2 - u2^2."""
    u1, u2 = k_pomet(t, x1, x2, x3)
    c, s = math.cos(t), math.sin(t)
    e = x1 + x2 * c
    dV = e * (u1 - x2 * s + c * x1 * u2) + x2 * x1 * u2 + x3 * u2
    return dV, -e * e - u2 * u2


def unicycle_law(t, w):
    """(4.8): (v, omega) from the law k at time t and the unicycle state w."""
    wx, wy, wth = w
    c, s = math.cos(wth), math.sin(wth)
    x1 = wx * c + wy * s
    x2 = wx * s - wy * c
    u1, u2 = k_pomet(t, x1, x2, wth)
    return u1 + x2 * u2, u2


# --------------------------------------------------------------------------- closed loop
def _frac(x) -> Fraction:
    return Fraction(str(x))


def trace(T, r, tau, N, x0, u0, stop, rtol=RTOL, atol=ATOL, diagnostics=False,
          method="DOP853", max_step=math.inf):
    """Rows ``(t, x, y, theta, v, omega)`` at ``t_k = k T / N``, ``k = 0 .. stop N / T``."""
    Tf, rf, tf, Sf = _frac(T), _frac(r), _frac(tau), _frac(stop)
    h = Tf / N
    K = int(Sf / h)
    n_reset = int(Sf / Tf)  # resets i = 1 .. n_reset (those with iT <= stop)
    x0 = np.array(x0, float)
    u0 = (float(u0[0]), float(u0[1]))
    tau_ = float(tau)

    # breakpoint -> list of events (exact rational times)
    events: dict[Fraction, list] = {}

    def add(t, ev):
        events.setdefault(t, []).append(ev)

    for k in range(K + 1):
        add(k * h, ("grid", k))
    for i in range(1, n_reset + 1):
        add(i * Tf - rf - tf, ("open", i))
        if i * Tf - rf > 0:
            add(i * Tf - rf, ("meas", i))
        add(i * Tf, ("reset", i))
    for i in range(0, n_reset + 1):
        if i * Tf + tf <= Sf:
            add(i * Tf + tf, ("zd", i))
    add(Fraction(0), ("start",))
    order = {"start": 0, "meas": 1, "reset": 2, "zd": 3, "open": 4, "grid": 5}
    times = sorted(t for t in events if t <= Sf)

    z = x0.copy()      # controller state (z0 = x0)
    zd = None          # z(t - tau), active for t >= tau
    p = None           # plant, active for t >= 0
    acc: dict[int, np.ndarray] = {}  # pending predictor windows
    meas: dict[int, np.ndarray] = {}
    zpost = {0: x0.copy()}
    rows = []
    jumps = {}
    zlog, plog = {}, {}

    def ctrl(s, zz):  # controller output at time s (s >= 0) from its state z(s)
        return unicycle_law(s + tau_, zz)

    for a, b in zip(times, [*times[1:], None]):
        # ---- events at time a
        for ev in sorted(events[a], key=lambda e: order[e[0]]):
            kind = ev[0]
            if kind == "start":
                p = x0.copy()
            elif kind == "meas":
                meas[ev[1]] = p.copy()
            elif kind == "reset":
                i = ev[1]
                m = meas.get(i, x0)
                A, C, S = acc.pop(i)
                cm, sm = math.cos(m[2]), math.sin(m[2])
                znew = np.array([m[0] + C * cm - S * sm, m[1] + C * sm + S * cm, m[2] + A])
                jumps[i] = float(np.max(np.abs(znew - z)))
                z = znew
                zpost[i] = z.copy()
            elif kind == "zd":
                zd = zpost[ev[1]].copy()
            elif kind == "open":
                acc[ev[1]] = np.zeros(3)
            elif kind == "grid":
                k = ev[1]
                t_k = (k // N) * T + (k % N) * T / N
                v, om = ctrl(float(a), z)
                rows.append((t_k, p[0], p[1], p[2], v, om))
                if diagnostics:
                    zlog[k] = z.copy()
                    plog[k] = p.copy()
        if b is None:
            break
        # ---- integrate over [a, b]
        fa, fb = float(a), float(b)
        active_z = a >= 0
        active_zd = a >= tf
        keys = sorted(acc)
        parts = []
        if active_z:
            parts += [z, p]
        if active_zd:
            parts.append(zd)
        for i in keys:
            parts.append(acc[i])
        if not parts:
            continue
        y0 = np.concatenate(parts)

        def rhs(t, y, active_z=active_z, active_zd=active_zd, keys=keys):
            out = np.empty_like(y)
            j = 0
            if active_z:
                zz = y[0:3]
                v, om = ctrl(t, zz)
                out[0] = v * math.cos(zz[2])
                out[1] = v * math.sin(zz[2])
                out[2] = om
                pp = y[3:6]
                j = 6
                if active_zd:
                    zdd = y[6:9]
                    pv, pom = unicycle_law(t, zdd)  # = ctrl(t - tau, z(t - tau))
                    out[6] = pv * math.cos(zdd[2])
                    out[7] = pv * math.sin(zdd[2])
                    out[8] = pom
                    j = 9
                else:
                    pv, pom = u0
                out[3] = pv * math.cos(pp[2])
                out[4] = pv * math.sin(pp[2])
                out[5] = pom
            else:
                v, om = u0
            for _ in keys:
                A = y[j]
                out[j] = om
                out[j + 1] = v * math.cos(A)
                out[j + 2] = v * math.sin(A)
                j += 3
            return out

        y = solve(rhs, y0, fa, fb, rtol, atol, method, max_step)
        j = 0
        if active_z:
            z, p = y[0:3].copy(), y[3:6].copy()
            j = 6
            if active_zd:
                zd = y[6:9].copy()
                j = 9
        for i in keys:
            acc[i] = y[j:j + 3].copy()
            j += 3
    if diagnostics:
        return rows, dict(jumps=jumps, z=zlog, p=plog, h=h, tau=tf)
    return rows


def write(name: str, case: dict) -> None:
    """Write case ``name``'s trace and settings files (``reftools.write_trace``)."""
    write_trace(OUT, name, ("time", "plant.x", "plant.y", "plant.theta", "controller.v",
                            "controller.omega"), trace(**case), case["stop"],
                case["T"] / case["N"], RTOL, positive_zero=True)


# --------------------------------------------------------------------------- checks
def verify_law(n=20, horizon=200.0, seed=12345):
    """Task A: delay-free (1.4) with u = k_pomet(t, x); 20 random states, |x0| in [0.5, 3]."""
    rng = np.random.default_rng(seed)

    def rhs(t, x):
        u1, u2 = k_pomet(t, *x)
        return [u1, x[0] * u2, u2]

    ts = np.linspace(0.0, horizon, int(horizon * 100) + 1)
    worst_dv = -math.inf
    finals, expo = [], []
    for _ in range(n):
        d = rng.normal(size=3)
        x0 = d / np.linalg.norm(d) * rng.uniform(0.5, 3.0)
        t0 = rng.uniform(0.0, 2 * math.pi)
        s = solve_ivp(rhs, (t0, t0 + horizon), x0, method="DOP853", rtol=1e-10, atol=1e-10,
                      t_eval=t0 + ts)
        nrm = np.linalg.norm(s.y, axis=0)
        V = np.array([lyapunov(t, *s.y[:, i]) for i, t in enumerate(s.t)])
        worst_dv = max(worst_dv, float(np.max(np.diff(V))))
        m = ts >= 50
        expo.append(np.polyfit(np.log(ts[m]), np.log(nrm[m]), 1)[0])
        finals.append(nrm[-1])
        print(f"|x0| = {np.linalg.norm(x0):.3f}, t0 = {t0:.2f}: "
              f"|x(t0+50)| = {nrm[ts == 50][0]:.3e}, "
              f"|x(t0+{horizon:g})| = {nrm[-1]:.3e}, fit t^{expo[-1]:.2f}, "
              f"V(end)/V(0) = {V[-1] / V[0]:.2e}")
    print(f"final norms in [{min(finals):.3e}, {max(finals):.3e}]; exponents on [50, {horizon:g}] "
          f"in [{min(expo):.2f}, {max(expo):.2f}]; largest V increment between samples "
          f"{worst_dv:.2e}")
    # dV/dt identity at random points
    err = 0.0
    for _ in range(1000):
        t, x1, x2, x3 = rng.uniform(-5, 5, 4)
        a, b = pomet_lyapunov_check(t, x1, x2, x3)
        err = max(err, abs(a - b) / (1 + abs(b)))
    print(f"dV/dt = -(x1 + x2 cos t)^2 - u2^2: max relative mismatch {err:.1e}")


def check(name="default"):
    """Accuracy and consistency checks for one case (run with --check)."""
    case = CASES[name]
    rows, d = trace(**case, diagnostics=True)
    ref = np.array(rows)
    h = case["T"] / case["N"]
    for label, kw in (("rtol=atol=5e-13", dict(rtol=RTOL / 2, atol=ATOL / 2)),
                      ("DOP853, max_step=h/8", dict(max_step=h / 8)),
                      ("Radau, rtol=atol=1e-12", dict(method="Radau"))):
        other = np.array(trace(**case, **kw))
        diff = np.max(np.abs(other - ref), axis=0)
        print(f"{name}: max |written - ({label})| per column: {diff[1:]}")
    jumps = d["jumps"]
    print(f"reset jumps: i=1: {jumps[1]:.2e}; max over i>=2: "
          f"{max(v for i, v in jumps.items() if i > 1):.2e}")
    lag = int(d["tau"] / d["h"])
    errs = [np.max(np.abs(d["z"][k] - d["p"][k + lag])) for k in d["z"] if k + lag in d["p"]]
    print(f"max |z(t) - p(t + tau)| over the trace: {max(errs):.2e}")
    # (4.2)-(4.3)-(4.8) against (1.4): the delay-free unicycle under (4.8), mapped by (4.2),
    # must follow (1.4) under k_pomet
    def uni(t, w):
        v, om = unicycle_law(t, w)
        return [v * math.cos(w[2]), v * math.sin(w[2]), om]

    def nhi(t, x):
        u1, u2 = k_pomet(t, *x)
        return [u1, x[0] * u2, u2]

    w0 = np.array(case["x0"], float)
    x0 = [w0[0] * math.cos(w0[2]) + w0[1] * math.sin(w0[2]),
          w0[0] * math.sin(w0[2]) - w0[1] * math.cos(w0[2]), w0[2]]
    tt = np.linspace(0, 50, 501)
    sw = solve_ivp(uni, (0, 50), w0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=tt).y
    sx = solve_ivp(nhi, (0, 50), x0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=tt).y
    mapped = np.array([sw[0] * np.cos(sw[2]) + sw[1] * np.sin(sw[2]),
                       sw[0] * np.sin(sw[2]) - sw[1] * np.cos(sw[2]), sw[2]])
    print("(4.2) of the unicycle under (4.8) vs (1.4) under k: max diff "
          f"{np.max(np.abs(mapped - sx)):.1e}")
    nrm = np.linalg.norm(ref[:, 1:4], axis=1)
    for t in (25.0, 50.0, 100.0):
        print(f"|x(t)| at t = {t:g}: {nrm[np.argmin(np.abs(ref[:, 0] - t))]:.6e}")
    m = ref[:, 0] >= 25
    per = ref[m, 0]
    print(f"fit |x| ~ t^p on [25, 100]: p = {np.polyfit(np.log(per), np.log(nrm[m]), 1)[0]:.3f}")
    # envelope: max of |x| over each 2*pi window
    tw, mw = [], []
    for a in np.arange(25.0, 100.0 - 2 * math.pi, 2 * math.pi):
        sel = (ref[:, 0] >= a) & (ref[:, 0] < a + 2 * math.pi)
        tw.append(a + math.pi)
        mw.append(nrm[sel].max())
    print(f"fit of the 2 pi envelope of |x| on [25, 100]: p = "
          f"{np.polyfit(np.log(tw), np.log(mw), 1)[0]:.3f}")


if __name__ == "__main__":
    main(OUT, CASES, write, {"--verify-law": verify_law, "--check": check})
