"""The Python API: your own loop, run, plotted, packed, swept and analysed from Python.

A loop comes from a loop file (``load``), from matrices or a python-control
``StateSpace`` (``lti``), or from a model file (``model``); each returns a
``Loop``, the typed description every command runs. Then

- ``run`` co-simulates it and returns a
  ``Result`` (one numpy array per signal:
  ``result["plant.x1"]``, ``result.signals``, ``result.to_pandas()``);
- ``plot`` returns a matplotlib ``Figure`` (pyplot is not touched, nor the backend);
- ``build`` writes the loop's FMUs, named after it, with its values as their start
  values (ready to instantiate with no parameter set), and a wiring sheet: your
  controller (``only=["controller"]``) to take into your own tool chain;
- ``to_ssp`` packs an SSP archive (``jacobi=True`` for libcosim and Ecos);
- ``sweep`` runs a grid and returns one row of metrics per point (``iter_sweep``
  hands them on one at a time, in memory bounded at any grid size);
- ``critical_delay`` gives the largest measurement delay the uncompensated loop
  survives (LTI).

**One face.** Every function that takes a loop takes it in the same three forms: a
``Loop``, a loop file's path (str or Path) or a scenario's name,
with overrides (``sets=["r=0.4"]`` or ``sets={"r": 0.4}``); ``sweep`` builds each
grid point of a ``Loop`` again from the loop-file data it keeps
(``origin``). The same functions are importable from
``delaycomp`` itself (``delaycomp.run``, ``delaycomp.sweep``, ...), imported on first use.
A message names what was passed in a short form (``short``).

Failures raise named exceptions, all ``DelaycompError``:
``ParameterError`` (a value out of range, the sign guard),
``BadFileError``, ``ModelError``,
``SimulationFailed`` (a run stopped early; its rows are in
``exc.result``).

**The sign.** delaycomp, like the paper, applies ``u = K x``; python-control's
``lqr``/``dlqr`` return ``K`` for ``u = -K x``: pass ``-K``. A ``K`` with which the
delay-free sampled loop is unstable is refused unless ``allow_unstable=True``.

Examples
--------
A double integrator with two delays, compensated against uncompensated:

>>> import numpy as np
>>> from delaycomp import api
>>> A = [[0.0, 1.0], [0.0, 0.0]]
>>> B = [[0.0], [1.0]]
>>> K = [[-1.0, -1.6]]                     # u = K x (python-control's lqr gives -K)
>>> loop = api.lti(A, B, K, T=0.2, r=0.36, tau=0.4, N=20, x0=[1.0, 0.0])
>>> res = api.run(loop, stop_time=12.0, engine="inprocess")
>>> bool(abs(res["plant.x1"][-1]) < 1e-2)
True
>>> bare = api.run(api.lti(A, B, K, T=0.2, r=0.36, tau=0.4, N=20, x0=[1.0, 0.0],
...                        mode="uncompensated"), 12.0, engine="inprocess")
>>> bool(np.abs(bare["plant.x1"]).max() > np.abs(res["plant.x1"]).max())
True
>>> fig = api.plot([res, bare], labels=["compensated", "uncompensated"])
>>> type(fig).__name__
'Figure'

The same from ``delaycomp`` itself, with a scenario by name:

>>> import delaycomp
>>> delaycomp.run is api.run
True
>>> delaycomp.run("example-3.6", 5.0, engine="inprocess", sets={"r": 0.5}).success
True
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from delaycomp.api._common import LoopLike, as_loop, fmi_version, fmu_kind
from delaycomp.api._export import build, export_c, to_ssp
from delaycomp.api._studies import (
    critical_delay,
    critical_delay_report,
    critical_delay_table,
    iter_sweep,
    robustness,
    sweep,
)
from delaycomp.errors import (
    BadFileError,
    DelaycompError,
    ParameterError,
    SimulationFailed,
    short,
)
from delaycomp.maths.channel import Channel
from delaycomp.maths.model import ModelError
from delaycomp.orchestrator.simulate import Result
from delaycomp.system import Loop, Origin
from delaycomp.system import lti_loop as _lti_loop
from delaycomp.system import model_loop as _model_loop
from delaycomp.system.loopfile import (
    DEFAULT_N,
    SignError,
    check_sign,
    with_channels,
)

__all__ = ["BadFileError", "DelaycompError", "Loop", "ModelError", "ParameterError",
           "Result", "SignError", "SimulationFailed", "build", "choose_fmus", "critical_delay",
           "critical_delay_report", "critical_delay_table", "export_c", "iter_sweep", "load",
           "lti", "model", "plot", "robustness", "run", "sweep", "to_ssp"]


def load(source: LoopLike, sets: Sequence[str] | Mapping[str, object] = (),
         **overrides) -> Loop:
    """The loop of a loop file (TOML), a scenario or a ``Loop``, with key overrides.

    Parameters
    ----------
    source : Loop, str or Path
        A loop file's path (see ``delaycomp.system.loopfile`` for its keys), a
        scenario's name (``delaycomp list``) or a ``Loop`` (built again with the
        overrides from the loop-file data it keeps).
    sets : sequence of str or mapping, optional
        Overrides as ``--set`` takes them: ``["r=0.4", "controller.K=-1,-2"]``, or a
        mapping ``{"r": 0.4, "plant.x0": [1, 0]}``.
    **overrides
        Keys to override; a section key is written with a double underscore: ``r=0.4``,
        ``plant__x0=[1, 0]``, ``controller__mode="uncompensated"``. Short names serve
        too: ``x0``, ``u0``, ``K``, ``mode`` and a model's own parameters
        (``long_key``). A scenario takes its own parameter
        names (``k``, ``r``, ...).

    Returns
    -------
    Loop

    Examples
    --------
    >>> from delaycomp import api
    >>> api.load("example-3.6", r=0.5)
    <Loop 'example-3.6' n=1 m=1 T=1 N=100>
    >>> loop = api.lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, x0=[1.0], name="ex")
    >>> api.load(loop, sets=["r=0.5"], K=-1.5).lti.K.tolist()
    [[-1.5]]
    """
    return as_loop(source, sets, overrides)


def _matrices(plant, B):
    """``(A, B)`` from arrays or a continuous-time python-control ``StateSpace``."""
    if B is not None:
        return np.atleast_2d(np.asarray(plant, dtype=float)), np.atleast_2d(
            np.asarray(B, dtype=float))
    if not all(hasattr(plant, a) for a in ("A", "B", "D")):
        raise ParameterError("lti(plant, B=None, ...): plant must be the matrix A (with B) "
                             "or a python-control StateSpace")
    dt = getattr(plant, "dt", 0)
    if dt not in (0, None):
        raise ParameterError(f"StateSpace with dt = {dt!r} is not allowed: the plant must be "
                             "continuous-time (dt = 0); delaycomp samples it exactly")
    if np.any(np.asarray(plant.D, dtype=float) != 0):
        raise ParameterError("StateSpace with D != 0 is not allowed: the measured output is "
                             "the state (D = 0)")
    return np.asarray(plant.A, dtype=float), np.asarray(plant.B, dtype=float)


def lti(plant, B=None, K=None, *, T: float, r: float = 0.0, tau: float = 0.0,
        N: int = DEFAULT_N, x0, u0=None, mode: str = "compensated",
        r_true: float | None = None, tau_true: float | None = None,
        stop_time: float | None = None, name: str = "loop",
        allow_unstable: bool = False, pad: bool = False,
        meas_channel: Channel | None = None,
        input_channel: Channel | None = None) -> Loop:
    """An LTI loop: plant ``x' = A x + B u(t - tau)``, measured as ``x(t - r)`` every ``T``,
    controlled by ``u = K x`` on the predicted state (``mode="compensated"``) or on the
    sample itself (``"uncompensated"``) through a zero-order hold.

    Parameters
    ----------
    plant : array_like or control.StateSpace
        ``A`` (n x n), with ``B`` given; or a continuous-time python-control ``StateSpace``
        with ``D = 0`` (then ``B`` is taken from it).
    B : array_like, optional
        ``B`` (n x m).
    K : array_like
        The gain (m x n) of ``u = K x``, the paper's sign. python-control's ``lqr`` and
        ``dlqr`` return ``K`` for ``u = -K x``: pass ``-K``.
    T, r, tau, N : float, float, float, int
        Sampling period, measurement delay, input delay (a multiple of ``T`` unless
        ``pad``), base steps per period (``r`` and ``tau`` are multiples of ``h = T/N``).
    x0, u0 : array_like
        Constant histories of ``x`` on ``[-r, 0]`` and of ``u`` on ``[-r - tau, 0)``
        (``u0`` defaults to zeros).
    allow_unstable : bool
        Let through a ``K`` with which the delay-free sampled loop is unstable (otherwise
        ``SignError``, which gives its spectral radius).
    pad : bool
        Accept a ``tau`` that is no multiple of ``T`` (Remark 3.3(b)): the controller
        predicts over ``tau_eff = ceil(tau/T) T`` and delays its own output by ``tau_eff -
        tau``, so the plant sees ``u(t - tau_eff)`` (the loop file's ``[controller] pad``).
        Without it such a ``tau`` is refused, the message naming ``pad``.
    meas_channel, input_channel : delaycomp.maths.channel.Channel, optional
        A network channel in the place of the measurement or the input delay (the loop
        file's ``[meas_delay]`` and ``[input_delay]``): per-packet delays, loss, a
        delivery policy. Its ``delay`` is the least delay; ``0`` (the ``Channel``
        default) takes the loop's true delay (``r_true``, ``tau_true``). ``None``: the
        constant delay, as without a channel.

    Returns
    -------
    Loop

    Examples
    --------
    >>> from delaycomp.maths.channel import Channel
    >>> net = Channel(distribution="uniform", jitter=0.1, loss_model="bernoulli", loss=0.1,
    ...               seed=7)
    >>> loop = lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, x0=[1.0], meas_channel=net)
    >>> loop.by_role("meas_delay").source
    BuiltinFmu(kind='channel', config={'n': 1})
    >>> res = run(loop, stop_time=20.0, engine="inprocess")
    >>> bool(abs(res["plant.x"][-1]) < 1e-2)    # still settles: a jitter of 0.1 s, 10% lost
    True
    """
    A, B = _matrices(plant, B)
    if K is None:
        raise ParameterError("lti(): K (u = K x) is required")
    K = np.atleast_2d(np.asarray(K, dtype=float))
    u0 = np.zeros(B.shape[1]) if u0 is None else u0
    pad = bool(pad)
    loop = _lti_loop(A, B, K, T, r, tau, N, mode, x0, u0, r_true=r_true, tau_true=tau_true,
                     name=name, title=f"LTI loop {name}", stop_time=stop_time, pad=pad)
    if not allow_unstable:
        check_sign(A, B, K, T)
    d = loop.lti
    assert d is not None
    tables = channel_tables(meas_channel, input_channel)
    data = _top_data(
        loop, d.r, d.tau, d.r_true, d.tau_true,
        plant={"A": d.A.tolist(), "B": d.B.tolist(), "x0": np.ravel(d.x0).tolist()},
        controller={"K": d.K.tolist(), "u0": np.ravel(d.u0).tolist(), "mode": d.mode,
                    "allow_unstable": bool(allow_unstable),
                    **({"pad": True} if pad else {})}, **tables)
    return with_channels(loop, tables, Path.cwd(), f"loop {name!r}").replace(
        origin=Origin(data))


def channel_tables(meas_channel: Channel | None = None,
                   input_channel: Channel | None = None) -> dict:
    """The loop-file tables ``[meas_delay]`` and ``[input_delay]`` of two channels (each
    ``None`` for none): every field of a ``Channel`` that differs from its default, its
    trace as a list of delays; a ``delay`` of 0 is left out (the loop's true delay).

    Examples
    --------
    >>> channel_tables(Channel(distribution="uniform", jitter=0.1, seed=3))
    {'meas_delay': {'distribution': 'uniform', 'jitter': 0.1, 'seed': 3}}
    """
    tables: dict[str, dict] = {}
    for role, ch in (("meas_delay", meas_channel), ("input_delay", input_channel)):
        if ch is None:
            continue
        if not isinstance(ch, Channel):
            raise ParameterError(f"{role.split('_')[0]}_channel = {short(ch)} is not "
                                 "allowed: must be a delaycomp.maths.channel.Channel")
        table: dict = {}
        for f in dataclasses.fields(Channel):
            value = getattr(ch, f.name)
            if value != f.default and value is not None:
                table[f.name] = list(value) if f.name == "trace" else value
        tables[role] = table
    return tables


def _top_data(loop: Loop, r: float, tau: float, r_true, tau_true, **sections) -> dict:
    """The loop-file data of a loop built by ``lti`` or ``model`` (its
    ``origin``): what a sweep of it resolves each point from."""
    data: dict = {"name": loop.name, "title": loop.title, "T": loop.T, "N": loop.N,
                  "r": r, "tau": tau, **sections}
    for key, value in (("r_true", r_true), ("tau_true", tau_true),
                       ("stop_time", loop.stop_time)):
        if value is not None:
            data[key] = value
    return data


def model(path: str | Path, *, T: float, r: float = 0.0, tau: float = 0.0,
          N: int = DEFAULT_N, x0, u0=None, mode: str = "compensated",
          predictor: str | None = None, pad: bool = False,
          stop_time: float | None = None, meas_channel: Channel | None = None,
          input_channel: Channel | None = None, **parameters) -> Loop:
    """A loop around a model file (the plant ``f`` and its delay-free feedback ``k``; see
    ``delaycomp.maths.model``); ``parameters`` are the model's own. ``meas_channel`` and
    ``input_channel``: network channels in the delays' places, as for ``lti``.

    ``mode="uncompensated"`` applies the feedback to the sample itself instead of the
    prediction (the baseline the predictor is compared with).
    """
    from delaycomp.maths.model import load_model

    if mode not in ("compensated", "uncompensated"):
        raise ParameterError(f"mode = {short(mode)} is not allowed: must be compensated or "
                             "uncompensated")
    path = Path(path).resolve()
    m = load_model(path).m
    u0 = np.zeros(m) if u0 is None else u0
    loop = _model_loop(path, T, r, tau, N, x0, u0, params=parameters,
                       predictor="none" if mode == "uncompensated" else predictor, pad=pad,
                       name=path.stem, title=f"model {path.stem}", stop_time=stop_time)
    controller: dict = {"mode": mode, "u0": np.ravel(np.asarray(u0, dtype=float)).tolist(),
                        "pad": bool(pad), **parameters}
    if predictor is not None:
        controller["predictor"] = predictor
    tables = channel_tables(meas_channel, input_channel)
    return with_channels(loop, tables, Path.cwd(), f"loop {path.stem!r}").replace(
        origin=Origin(_top_data(
            loop, r, tau, None, None,
            plant={"model": str(path),
                   "x0": np.ravel(np.asarray(x0, dtype=float)).tolist()},
            controller=controller, **tables)))


def choose_fmus(loop: LoopLike, fmus: str = "auto", fmu_dir: str | Path | None = None,
                engine: str = "fmu", fmi: int = 2, clocked: bool = False
                ) -> tuple[dict[str, Path] | None, str | None]:
    """The FMU files a run of ``loop`` uses, and why not the native ones where it could
    have: ``(files, why)``, ``files`` ``None`` for the Python FMUs of the build cache.

    ``fmus`` (``FMU_KINDS``): ``auto`` takes the native C FMUs where the loop has them
    here (``why`` says otherwise: no native twin, no C compiler, a model that does not
    translate), ``native`` only those (``ValueError`` where there are none),
    ``python`` the Python ones. ``engine="inprocess"`` runs no FMU files. ``run`` and the
    command line choose through here.

    ``fmu_dir``: the FMUs there under their own names come first, what ``delaycomp build
    --out fmu_dir`` wrote (``delaycomp.fmu.twins.fmus_in_dir``): ``auto`` takes their kind,
    native or Python, and builds nothing they cover; one that is stale (another delaycomp
    version, other sources) or of the wrong kind (a Python FMU where native ones run or the
    reverse, another FMI version, other dimensions) raises ``BadFileError``, one line
    naming it and what to do. Missing Python FMUs are built into ``fmu_dir``, missing
    native ones into ``fmu_dir/native``.

    ``fmi=3``: FMI 3.0 native FMUs (``delaycomp.fmu.fmi3``; native only: ``auto`` is
    ``native``), missing ones built into ``fmu_dir/native/fmi3``; a user's FMU file of the
    loop (another tool's FMI 2.0 plant) runs beside them as it is. ``clocked=True`` (with
    ``fmi=3``):
    the LTI controller's clocked variant, its sampling driven by an FMI 3.0 clock of
    interval T (``docs/reference/fmi3.md``).

    Examples
    --------
    >>> loop = lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, x0=[1.0])
    >>> choose_fmus(loop, "python")
    (None, None)
    """
    fmu_kind(fmus)
    fmi = fmi_version(fmi, clocked)
    loop = as_loop(loop)
    if fmi == 3 and (engine != "fmu" or fmus == "python"):
        raise ParameterError(f"fmi = 3 is not allowed with "
                             f"{'fmus = python' if engine == 'fmu' else 'engine = ' + engine}"
                             ": delaycomp's FMI 3.0 FMUs are the native C ones (engine = "
                             "fmu, fmus = native or auto)")
    if engine != "fmu":
        if fmus == "native":
            raise ParameterError("fmus = 'native' is not allowed with engine = 'inprocess' "
                                 "(the Python slaves run in this process)")
        return None, None
    from delaycomp.fmu import twins

    return twins.choose(loop, fmus, Path(fmu_dir) if fmu_dir else None, fmi, clocked)


def run(loop: LoopLike, stop_time: float | None = None, *, engine: str = "fmu",
        fmu_dir: str | Path | None = None, fmus: str | Mapping[str, Path] = "auto",
        every: int = 1, sink=None, keep: bool = True, progress=None,
        watchdog: float | None = None,
        sets: Sequence[str] | Mapping[str, object] = (), fmi: int = 2,
        clocked: bool = False, stepping: str = "auto") -> Result:
    """Co-simulate ``loop`` from 0 to ``stop_time`` (default: the loop's), one row per base
    step; ``engine="inprocess"`` runs the Python FMUs' slaves without the FMI layer (the
    same numbers, faster). ``fmus`` (``FMU_KINDS``): with the FMU engine, the native C
    FMUs where the loop has them (``auto``: LTI loops and model files that translate, with
    a C compiler; a note in ``result.notes`` says when the Python FMUs ran instead), only
    native ones, or the Python ones (``choose_fmus``); or the FMU file of each
    instance, by name (an SSP archive's). The FMUs of ``fmu_dir`` come first, native or
    Python, as ``delaycomp build --out fmu_dir`` wrote them (``choose_fmus``).

    The rest is for long runs (as the command line's ``run``): a row every ``every`` base
    steps; ``sink(t, row)`` receives each row as it is made
    (``CsvStream``); ``keep=False`` keeps no rows in the
    result; ``progress(k)`` hears the base step reached. Raises ``SimulationFailed``
    if the run stops early (its rows so far in ``exc.result``).

    An FMU file of another tool in the loop runs in a child process of its own; a call of
    it that takes longer than ``watchdog`` seconds (default: 10 s, or 100 base steps if
    longer) stops the run, as does the FMU ending or crashing its process
    (``delaycomp.orchestrator.isolated``).

    ``loop`` is a ``Loop``, a loop file's path or a scenario's name, with ``sets``
    (``["r=0.4"]`` or ``{"r": 0.4}``) as ``load`` takes them.

    ``fmi=3`` runs delaycomp's FMUs as FMI 3.0 native FMUs (``choose_fmus``): the same
    numbers, bit for bit, as the FMI 2.0 ones; with ``clocked=True`` the controller is the
    clocked one, its ticks scheduled in event mode (the same numbers again).

    ``stepping`` (``STEPPING``): ``auto`` hands a loop whose FMUs are all native ones to the
    native stepping core (C: the same FMI calls in the same order, the same rows bit for
    bit; ``result.stepped_by`` says ``native-core``, else ``python`` and
    ``result.stepping_note`` why); ``native-core`` asks for the core (``ParameterError``
    where it cannot step the loop); ``python`` the Python master.

    Examples
    --------
    >>> res = run("example-3.6", 5.0, engine="inprocess", sets={"r": 0.5})
    >>> float(res.times[-1]), len(res.times)
    (5.0, 501)
    """
    from delaycomp.orchestrator.isolated import check_watchdog
    from delaycomp.orchestrator.simulate import check_stepping, run_loop

    fmi_version(fmi, clocked)  # also where ``fmus`` names the files
    check_stepping(stepping, engine)
    loop = as_loop(loop, sets)
    stop = loop.stop_time if stop_time is None else stop_time
    if stop is None:
        raise ParameterError("stop_time is required (the loop has none)")
    if watchdog is not None:
        check_watchdog(watchdog)
    chosen: dict[str, Path] | None
    why: str | None
    if isinstance(fmus, Mapping):
        chosen, why = dict(fmus), None
    else:
        chosen, why = choose_fmus(loop, fmus, fmu_dir, engine, fmi, clocked)
    result = run_loop(loop, stop, Path(fmu_dir) if fmu_dir else None, engine=engine,
                      fmus=chosen, every=every, sink=sink, keep=keep, progress=progress,
                      watchdog=watchdog, stepping=stepping)
    if why:
        result.notes.append(f"the Python FMUs ran (no native ones here: {why})")
    if not result.success:
        raise SimulationFailed(result.message, result)
    return result


def plot(results, title: str = "", labels: Sequence[str] | None = None):
    """A matplotlib ``Figure`` of one result or several (one line each, ``labels`` in the
    legend); one panel per signal. The backend is not touched: save it with
    ``fig.savefig(...)`` or show it in a notebook."""
    from delaycomp.plotting import figure

    return figure(results, title, labels)
