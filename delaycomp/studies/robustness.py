"""Robustness of an LTI loop to a network channel: a Monte Carlo map over jitter x loss.

For a loop file (its ``[meas_delay]``/``[input_delay]`` channel tables the base; a role
without a table is the constant delay the loop gives it), every point of a grid of
**jitter** amplitudes x **loss** rates sets, on one channel (``on``: the measurement's by
default, or the input's), ``distribution`` with that ``jitter`` and a Bernoulli loss of
that rate (``loss_model = "bernoulli"``); the table's other keys (``delay``, ``policy``,
``max_delay``, ``period``, ``shape``) hold. Each point runs ``runs`` seeds in each
**mode** (``compensated``, ``uncompensated``; ``stamped``, the time-stamp controller,
once the batch engine takes it: ``stamped_available``), on the batch engine
(``delaycomp.studies.batch.run_lti_channels``: one call per grid point and chunk of
modes x seeds, equal to the per-point in-process runs, ``tests/test_robustness.py``).

**Seeds.** Run ``i`` (``0 .. runs - 1``) of every grid point and every mode draws the swept
channel from seed ``(seed + i) mod 2^31`` and the other channel (where the loop file has
one) from ``(seed + runs + i) mod 2^31``: the same draws (the same uniform numbers) at
every point and in every mode (common random numbers), so that the differences across the
map and between the modes are the parameters', not the draws'; and the map is the same
whatever the chunking. The ``seed`` keys of the tables are replaced.

**Per grid point and mode:**

- ``stable``: the runs the engine calls stable, ``p_stable = stable / runs``: a run is
  stable where the per-period growth rate ``rho`` of ``|x|`` fitted over the last four
  fifths of its periods (the sweep's ``rho``, ``delaycomp.studies.batch``) is below 1; a
  run that diverged (its state not finite: ``diverged``) is unstable. ``P(stable)`` is
  thus the probability that the loop's state decays over the run's horizon
  (``stop_time``), an empirical rate, not an asymptotic one: a slow decay or growth near
  ``rho = 1`` needs a long enough ``stop_time`` to show.
- ``p_low``, ``p_high``: the Wilson score 95 % interval of ``p_stable`` (``wilson``).
- ``cost_p50``, ``cost_p90``, ``cost_p99``: quantiles of the quadratic cost
  ``sum_k h (|x_k|^2 + |v_k|^2)`` (``v`` the plant's input) over the runs;
  ``final_p50``, ``final_p90``, ``final_p99``: of ``|x|`` at the stop time. Empirical
  quantiles by the inverted distribution function (an order statistic: no interpolation,
  so ``inf``, a diverged run's cost, is a value like the others).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from delaycomp.errors import ParameterError
from delaycomp.maths.channel import Channel

#: the channel the grid acts on
ROLES = ("meas_delay", "input_delay")
#: the jitter's distributions (``delaycomp.maths.channel``; a ``trace`` has no amplitude)
JITTER_DISTRIBUTIONS = ("uniform", "exponential", "gamma")
#: the modes: the controller's ``[controller]`` keys for each, and whether the batch
#: engine must read the channel's time stamps (``run_lti_channels(stamps=True)``)
MODE_KEYS: dict[str, tuple[dict, bool]] = {
    "compensated": ({"mode": "compensated"}, False),
    "uncompensated": ({"mode": "uncompensated"}, False),
    "stamped": ({"mode": "compensated", "stamps": True}, True),
}
#: the modes run by default
DEFAULT_MODES = ("compensated", "uncompensated")
#: the largest seed (``delaycomp.maths.channel.SEED_MAX``)
SEED_MOD = 2**31
#: the most runs per grid point
RUNS_MAX = 10_000_000
#: the batch engine's points per call at most, and the shown-packet table's size bound
CHUNK_MAX = 16384
CHUNK_CELLS = 2**24
#: ``plot_map`` writes P(stable) on the cells of grids of at most this many cells
ANNOTATE_MAX = 150
#: the quantiles reported
QUANTILES = (50, 90, 99)
#: z of the two-sided 95 % normal interval
Z95 = 1.959963984540054
#: the CSV's columns, in order (docs/reference/cli.md, ``delaycomp robustness``)
COLUMNS = ("jitter", "loss", "mode", "runs", "stable", "p_stable", "p_low", "p_high",
           "cost_p50", "cost_p90", "cost_p99", "final_p50", "final_p90", "final_p99",
           "diverged")


def stamped_available() -> bool:
    """Whether the batch engine reads the channel's time stamps
    (``run_lti_channels(..., stamps=True)``): the ``stamped`` mode runs only then."""
    from delaycomp.studies import batch

    return "stamps" in inspect.signature(batch.run_lti_channels).parameters


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a probability from ``k`` successes in ``n`` trials
    (95 % by default): ``(c - w, c + w) / (1 + z^2/n)`` with ``c = p + z^2/(2n)``,
    ``w = z sqrt(p(1-p)/n + z^2/(4n^2))``; within ``[0, 1]`` and not empty at ``k = 0``
    or ``k = n``.

    Examples
    --------
    >>> [round(v, 4) for v in wilson(0, 100)]
    [0.0, 0.037]
    >>> [round(v, 4) for v in wilson(50, 100)]
    [0.4038, 0.5962]
    """
    p = k / n
    q = z * z / n
    centre = p + q / 2
    half = z * math.sqrt(p * (1 - p) / n + q / (4 * n))
    low = 0.0 if k == 0 else max(0.0, (centre - half) / (1 + q))  # 0 and 1 exactly at
    high = 1.0 if k == n else min(1.0, (centre + half) / (1 + q))  # the ends (no round-off)
    return low, high


def quantiles(values: np.ndarray, qs: Sequence[float] = QUANTILES) -> list[float]:
    """The ``qs`` percentiles of ``values`` by the inverted distribution function (the
    least value with at least ``q %`` of the values at or below it; ``inf`` counts).

    >>> quantiles(np.array([3.0, 1.0, np.inf, 2.0]), (50, 90))
    [2.0, inf]
    """
    return [float(v) for v in np.percentile(values, list(qs), method="inverted_cdf")]


@dataclass
class RobustnessMap:
    """The result of ``robustness``: ``rows`` in grid order (jitter slowest, then loss,
    then mode), each a dict of ``COLUMNS``; ``array(column, mode)`` gives one column as a
    ``(len(jitter), len(loss))`` array."""

    jitter: tuple[float, ...]
    loss: tuple[float, ...]
    modes: tuple[str, ...]
    runs: int
    seed: int
    on: str
    distribution: str
    stop_time: float
    rows: list[dict] = field(default_factory=list)

    def array(self, column: str, mode: str) -> np.ndarray:
        """``column`` of ``mode`` over the grid, shape ``(len(jitter), len(loss))``."""
        values = [row[column] for row in self.rows if row["mode"] == mode]
        return np.array(values, dtype=float).reshape(len(self.jitter), len(self.loss))


@dataclass
class _StudyPlan:
    data: dict
    base: Path
    design: object
    tables: dict[str, dict]
    true_delay: dict[str, float]
    h: float


def _plan(source, sets, on: str, modes: Sequence[str], stop: float) -> _StudyPlan:
    """The loop's designs per mode (the loop without channels), its channel tables."""
    from delaycomp.studies.sweep_batch import lti_point
    from delaycomp.system import lti_designs
    from delaycomp.system.loopfile import CHANNEL_TABLES, build

    data = source.resolve(list(sets))
    tables = {role: dict(data[role]) for role in CHANNEL_TABLES if isinstance(
        data.get(role), dict)}
    plain = {k: v for k, v in data.items() if k not in CHANNEL_TABLES}
    points = []
    first = None
    for mode in modes:
        keys, _ = MODE_KEYS[mode]
        d = dict(plain)
        ctrl = {k: v for k, v in dict(d.get("controller", {})).items()
                if k not in ("stamps", "age_max")}
        d["controller"] = {**ctrl, "mode": keys["mode"]}
        loop = build(d, source.base, name=source.name, where=source.where)
        point = lti_point(loop)
        if isinstance(point, str):
            raise ParameterError(f"{source.where} is not allowed here: robustness takes an "
                                 f"LTI loop (plant A, B and gain K): {point}")
        points.append(point)
        first = first or loop
    assert first is not None and first.lti is not None
    lti = first.lti
    true = {"meas_delay": lti.r if lti.r_true is None else lti.r_true,
            "input_delay": lti.tau if lti.tau_true is None else lti.tau_true}
    design = lti_designs(points)
    if design is None:
        raise ParameterError(f"{source.where}: its modes do not stack into one batch")
    return _StudyPlan(data, source.base, design, tables, true, first.timing.T / first.timing.N)


def _channels(plan: _StudyPlan, on: str, jitter: float, loss: float, distribution: str):
    """The two channels of one grid point (``None`` for a role without one)."""
    from delaycomp.system.loopfile import channel_of

    out: dict[str, Channel | None] = {}
    for role in ROLES:
        table = dict(plan.tables.get(role, {}))
        if role == on:
            table.pop("trace", None)
            table.update(distribution=distribution, jitter=jitter,
                         loss_model="bernoulli", loss=loss)
        elif role not in plan.tables:
            out[role] = None
            continue
        table.pop("seed", None)
        ch = channel_of(table, role, plan.base, plan.true_delay[role], "robustness")
        try:
            ch.check()
        except ValueError as exc:
            raise ParameterError(f"{role}: {exc}") from None
        out[role] = ch
    return out


def check_grid(jitter: Sequence[float], loss: Sequence[float], runs: int, seed: int,
               on: str, modes: Sequence[str], distribution: str) -> None:
    """Refuse, in one line naming the parameter and what is allowed, a grid or option
    ``robustness`` does not take."""
    if not jitter or any(not (math.isfinite(j) and j >= 0) for j in jitter):
        raise ParameterError(f"jitter = {list(jitter)!r} is not allowed: must be one or more "
                             "finite numbers >= 0 [s]")
    if not loss or any(not (math.isfinite(v) and 0 <= v <= 1) for v in loss):
        raise ParameterError(f"loss = {list(loss)!r} is not allowed: must be one or more "
                             "numbers in 0 .. 1")
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or not (
            1 <= runs <= RUNS_MAX):
        raise ParameterError(f"runs = {runs!r} is not allowed: must be an integer from 1 to "
                             f"{RUNS_MAX}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not (
            0 <= seed < SEED_MOD):
        raise ParameterError(f"seed = {seed!r} is not allowed: must be an integer in 0 .. "
                             f"{SEED_MOD - 1}")
    if on not in ROLES:
        raise ParameterError(f"on = {on!r} is not allowed: must be one of {', '.join(ROLES)}")
    if distribution not in JITTER_DISTRIBUTIONS:
        raise ParameterError(f"distribution = {distribution!r} is not allowed: must be one "
                             f"of {', '.join(JITTER_DISTRIBUTIONS)}")
    allowed = [m for m in MODE_KEYS if m != "stamped" or stamped_available()]
    if not modes or len(set(modes)) != len(modes) or any(m not in allowed for m in modes):
        raise ParameterError(f"modes = {','.join(modes)!r} is not allowed: must be one or "
                             f"more of {', '.join(allowed)}, each once")


def robustness(source, jitter: Sequence[float], loss: Sequence[float], runs: int, *,
               seed: int = 0, on: str = "meas_delay",
               modes: Sequence[str] = DEFAULT_MODES, distribution: str = "uniform",
               sets: Iterable[str] = (), stop_time: float | None = None,
               chunk: int | None = None, array_backend: str = "numpy",
               progress: Callable[[int], None] | None = None) -> RobustnessMap:
    """The robustness map of an LTI loop file (``source``: a ``LoopFile``/``LoopData``,
    ``delaycomp.paper.scenarios.open_source``) over ``jitter`` x ``loss`` (see the module
    docstring). ``chunk``: runs per batch-engine call at most (default: from the run's
    length, at most ``CHUNK_MAX``; on a GPU every run of a grid point in one call, the
    engine chunking them in device memory); ``array_backend``: ``numpy``, ``cupy`` or
    ``auto`` (``delaycomp.studies.batch.channel_backend``: the same numbers on either);
    ``progress(k)`` hears each ``k`` runs done."""
    from delaycomp.studies import batch

    try:
        be = batch.channel_backend(array_backend)
    except batch.BatchError as exc:
        raise ParameterError(str(exc)) from None

    jitter = tuple(float(j) for j in jitter)
    loss = tuple(float(v) for v in loss)
    modes = tuple(modes)
    check_grid(jitter, loss, runs, seed, on, modes, distribution)
    stop = float(stop_time if stop_time is not None else (source.default_stop_time or 0.0))
    if not (math.isfinite(stop) and stop > 0):
        raise ParameterError("stop_time is not given: the loop file has none; give "
                             "stop_time (--stop-time) > 0 [s]")
    plan = _plan(source, sets, on, modes, stop)
    steps = round(stop / plan.h) + 1
    if chunk is None:
        chunk = (max(1, min(CHUNK_MAX, CHUNK_CELLS // steps)) if be.name == "numpy"
                 else len(modes) * runs)
    elif isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ParameterError(f"chunk = {chunk!r} is not allowed: must be an integer >= 1")
    other = "input_delay" if on == "meas_delay" else "meas_delay"
    run_ids = np.arange(runs, dtype=np.int64)
    seeds = {on: (seed + run_ids) % SEED_MOD, other: (seed + runs + run_ids) % SEED_MOD}
    # the batch: modes x seeds, mode slowest
    mode_of = np.repeat(np.arange(len(modes)), runs)
    run_of = np.tile(run_ids, len(modes))
    total = len(mode_of)
    result = RobustnessMap(jitter, loss, modes, runs, seed, on, distribution, stop)
    for j in jitter:
        for v in loss:
            channels = _channels(plan, on, j, v, distribution)
            stable = np.empty(total, dtype=np.int64)
            cost = np.empty(total)
            final = np.empty(total)
            failed = np.empty(total, dtype=bool)
            for lo in range(0, total, chunk):
                hi = min(total, lo + chunk)
                res = _run_chunk(batch, plan, modes, mode_of[lo:hi], run_of[lo:hi],
                                 channels, seeds, stop, be)
                stable[lo:hi] = res.stable
                assert res.cost is not None
                cost[lo:hi] = res.cost
                final[lo:hi] = res.final_norm
                failed[lo:hi] = ~np.asarray(res.success, dtype=bool)
                if progress is not None:
                    progress(hi - lo)
            for i, mode in enumerate(modes):
                sel = slice(i * runs, (i + 1) * runs)
                k = int(stable[sel].sum())
                low, high = wilson(k, runs)
                row = {"jitter": j, "loss": v, "mode": mode, "runs": runs, "stable": k,
                       "p_stable": k / runs, "p_low": low, "p_high": high}
                for q, val in zip(QUANTILES, quantiles(cost[sel])):
                    row[f"cost_p{q}"] = val
                for q, val in zip(QUANTILES, quantiles(final[sel])):
                    row[f"final_p{q}"] = val
                row["diverged"] = int(failed[sel].sum())
                result.rows.append(row)
    return result


def _run_chunk(batch, plan: _StudyPlan, modes, mode_of, run_of, channels, seeds, stop: float,
               backend):
    """One ``run_lti_channels`` call: the runs ``run_of`` in the modes ``mode_of`` (a
    chunk holds one or more modes; those that read stamps run in calls of their own)."""
    parts = []
    for stamped in (False, True):
        picked = np.flatnonzero([MODE_KEYS[modes[i]][1] == stamped for i in mode_of])
        if picked.size == 0:
            continue
        design = _take(plan.design, mode_of[picked])
        kwargs = {"stamps": True} if stamped else {}
        try:
            res = batch.run_lti_channels(
                design, stop, meas=channels["meas_delay"], inp=channels["input_delay"],
                meas_seeds=seeds["meas_delay"][run_of[picked]],
                input_seeds=seeds["input_delay"][run_of[picked]], backend=backend,
                **kwargs)
        except batch.BatchError as exc:
            raise ParameterError(str(exc)) from None
        parts.append((picked, res))
    if len(parts) == 1:
        return parts[0][1]
    n = len(mode_of)
    out = batch.BatchResult(*(np.empty(n, dtype=getattr(parts[0][1], f).dtype)
                              for f in ("rho", "stable", "final_norm", "peak_norm",
                                        "deadbeat_time", "success")))
    out.cost = np.empty(n)
    for picked, res in parts:
        for f in ("rho", "stable", "final_norm", "peak_norm", "deadbeat_time", "success",
                  "cost"):
            getattr(out, f)[picked] = getattr(res, f)
    return out


def _take(design, index: np.ndarray):
    """The points ``index`` of an ``LtiBatch`` (its arrays taken along the points)."""
    import dataclasses

    return dataclasses.replace(design, **{f.name: np.take(getattr(design, f.name), index,
                                                          axis=0)
                                          for f in dataclasses.fields(design)})


def write_csv(result: RobustnessMap, path: str | Path) -> None:
    """Write ``result.rows`` to ``path`` as CSV (``COLUMNS``; numbers to the bit, as
    ``repr`` writes them), through a ``.part`` file moved into place once written (removed
    if writing stops: no half-written file looks like a result)."""
    from delaycomp.studies.axes import format_value
    from delaycomp.studies.sweep_output import write_table

    write_table(path, COLUMNS, ([format_value(row["jitter"]), format_value(row["loss"]),
                                 row["mode"], *(_cell(row[c]) for c in COLUMNS[3:])]
                                for row in result.rows))


def _cell(value) -> str:
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    return repr(float(value))


def plot_map(result: RobustnessMap, path: str | Path, title: str = "") -> None:
    """Jitterbug-style heat maps over (jitter, loss): ``P(stable)`` (top row, one scale
    0 .. 1, each cell's value written on it for grids of at most ``ANNOTATE_MAX`` cells)
    and the median cost (bottom row, a logarithmic scale of each mode's own, so that a
    mode's trend shows however far the modes lie apart; grey where the median run
    diverged), one column per mode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from delaycomp.plotting import save

    modes = result.modes
    fig, axs = plt.subplots(2, len(modes), figsize=(4.6 * len(modes) + 0.6, 7.2),
                            squeeze=False, constrained_layout=True)
    x = np.asarray(result.jitter)
    y = np.asarray(result.loss)
    cmap = plt.get_cmap("viridis").with_extremes(bad="0.75")
    annotate = len(x) * len(y) <= ANNOTATE_MAX
    p_mesh = None
    for i, mode in enumerate(modes):
        p = result.array("p_stable", mode)
        ax = axs[0][i]
        p_mesh = ax.pcolormesh(x, y, p.T, shading="nearest", vmin=0.0, vmax=1.0,
                               cmap="RdYlGn")
        if annotate:
            for a, xv in enumerate(x):
                for b, yv in enumerate(y):
                    ax.text(xv, yv, f"{p[a, b]:.2f}", ha="center", va="center", fontsize=7)
        ax.set_title(f"{mode}: P(stable)")
        cost = result.array("cost_p50", mode)
        ok = cost[np.isfinite(cost) & (cost > 0)]
        norm = LogNorm(float(ok.min()), float(max(ok.max(), ok.min() * 1.0001))) \
            if ok.size else None
        ax = axs[1][i]
        c_mesh = ax.pcolormesh(x, y, np.ma.masked_invalid(
            np.where(np.isfinite(cost) & (cost > 0), cost, np.nan)).T,
            shading="nearest", cmap=cmap, norm=norm)
        ax.set_title(f"{mode}: median cost")
        fig.colorbar(c_mesh, ax=ax, label="median of sum h(|x|^2 + |v|^2)")
        for ax in (axs[0][i], axs[1][i]):
            ax.set_xlabel(f"jitter [s] ({result.on}, {result.distribution})")
            ax.set_ylabel("loss rate")
    if p_mesh is not None:
        fig.colorbar(p_mesh, ax=list(axs[0]), label="P(stable)")
    fig.suptitle(title or f"robustness: {result.runs} runs per point")
    save(fig, path)
    plt.close(fig)
