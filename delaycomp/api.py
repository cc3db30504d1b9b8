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
import json
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from delaycomp.errors import (
    BadFileError,
    DelaycompError,
    ParameterError,
    SimulationFailed,
    short,
)
from delaycomp.maths.channel import Channel
from delaycomp.maths.model import ModelError
from delaycomp.names import FMU_KINDS, array_element
from delaycomp.orchestrator.simulate import Result
from delaycomp.system import Loop, Origin
from delaycomp.system import lti_loop as _lti_loop
from delaycomp.system import model_loop as _model_loop
from delaycomp.system.loop import refuse_channel
from delaycomp.system.loopfile import (
    DEFAULT_N,
    SignError,
    check_sign,
    with_channels,
)

if TYPE_CHECKING:
    from delaycomp.studies.axes import Axis

__all__ = ["BadFileError", "DelaycompError", "Loop", "ModelError", "ParameterError",
           "Result", "SignError", "SimulationFailed", "build", "choose_fmus", "critical_delay",
           "critical_delay_report", "critical_delay_table", "export_c", "iter_sweep", "load",
           "lti", "model", "plot", "robustness", "run", "sweep", "to_ssp"]


#: a loop, as every function here takes one: a ``Loop``, a loop file's path, or a
#: scenario's name
LoopLike = Loop | str | Path


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
    return _as_loop(source, sets, overrides)


def _as_loop(source: LoopLike, sets: Sequence[str] | Mapping[str, object] = (),
             overrides: Mapping[str, object] | None = None) -> Loop:
    """The ``Loop`` of ``source`` with ``sets`` and ``overrides`` applied: the one
    reading of a loop for every function here (``open_source``:
    a ``Loop``, a loop file's path, a scenario's name; anything else is refused in
    one short line naming it)."""
    from delaycomp.paper.scenarios import open_source

    assignments = _assignments(sets, overrides)
    if isinstance(source, Loop) and not assignments:
        return source
    return open_source(source).loop(assignments)


def _assignments(sets: Sequence[str] | Mapping[str, object] = (),
                 overrides: Mapping[str, object] | None = None) -> list[str]:
    """``sets`` (``NAME=VALUE`` texts, or a mapping) and ``overrides`` (``section__key``
    names) as ``NAME=VALUE`` texts, as ``--set`` takes them."""
    if isinstance(sets, str):
        raise ParameterError(f"sets = {short(sets)} is not allowed: give a list of "
                             "NAME=VALUE texts or a mapping")
    items: list[str | tuple[str, object]] = [
        *(sets.items() if isinstance(sets, Mapping) else sets),
        *((k.replace("__", "."), v) for k, v in (overrides or {}).items())]
    return [item if isinstance(item, str) else f"{item[0]}={_text(item[1])}"
            for item in items]


def _text(value) -> str:
    """A Python value as ``--set`` reads it (numbers to the bit, lists as TOML arrays)."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_text(v)}"
                               for k, v in value.items()) + "}"
    if isinstance(value, (int, float, np.number)):
        return repr(float(value))
    try:
        return json.dumps(np.asarray(value, dtype=float).tolist())
    except (TypeError, ValueError):
        return str(value)


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


#: which FMUs ``run`` and ``to_ssp`` use: the native C FMUs where the loop has
#: them here, else the Python ones (``auto``, the default, as the CLI); only native ones
#: (an error where there are none); only the Python ones


def _fmu_kind(fmus: str) -> None:
    if fmus not in FMU_KINDS:
        raise ParameterError(f"fmus = {short(fmus)} is not allowed: must be one of "
                             f"{', '.join(FMU_KINDS)}")


def _fmi_version(fmi, clocked=False) -> int:
    """``fmi`` checked (2 or 3), and ``clocked`` with it (a bool, true only with 3)."""
    if fmi not in (2, 3) or isinstance(fmi, bool):
        raise ParameterError(f"fmi = {short(fmi)} is not allowed: must be 2 or 3 (the FMI "
                             "version of delaycomp's FMUs)")
    if not isinstance(clocked, bool):
        raise ParameterError(f"clocked = {short(clocked)} is not allowed: must be true or "
                             "false")
    if clocked and fmi != 3:
        raise ParameterError("clocked = true is not allowed with fmi = 2: the clocked "
                             "controller is an FMI 3.0 FMU (fmi = 3)")
    return int(fmi)


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
    --out fmu_dir`` wrote (``delaycomp.fmu.native.fmus_in_dir``): ``auto`` takes their kind,
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
    _fmu_kind(fmus)
    fmi = _fmi_version(fmi, clocked)
    loop = _as_loop(loop)
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
    from delaycomp.fmu import native

    native_dir = Path(fmu_dir) / "native" if fmu_dir else None
    found: dict[str, Path] = {}
    if fmu_dir:
        there, found = native.fmus_in_dir(loop, Path(fmu_dir), fmus, fmi, clocked)
        if there == "python" and fmus == "auto":  # what build --out left there
            try:  # the note of a loop that has no native FMUs anyway
                native.check_native(loop, fmi, clocked)
            except ValueError as exc:
                return None, native.why_not_native(exc)
            from delaycomp.progress import detail

            detail(f"the Python FMUs run this loop: {fmu_dir} holds Python ones")
            return None, None
    if fmus == "python":
        return None, None
    if fmus == "native" or fmi == 3:
        return native.native_fmus(loop, native_dir, fmi, clocked, found), None
    return native.native_or_why(loop, native_dir, found=found)


def run(loop: LoopLike, stop_time: float | None = None, *, engine: str = "fmu",
        fmu_dir: str | Path | None = None, fmus: str | Mapping[str, Path] = "auto",
        every: int = 1, sink=None, keep: bool = True, progress=None,
        watchdog: float | None = None,
        sets: Sequence[str] | Mapping[str, object] = (), fmi: int = 2,
        clocked: bool = False) -> Result:
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

    Examples
    --------
    >>> res = run("example-3.6", 5.0, engine="inprocess", sets={"r": 0.5})
    >>> float(res.times[-1]), len(res.times)
    (5.0, 501)
    """
    from delaycomp.orchestrator.isolated import check_watchdog
    from delaycomp.orchestrator.simulate import run_loop

    _fmi_version(fmi, clocked)  # also where ``fmus`` names the files
    loop = _as_loop(loop, sets)
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
                      watchdog=watchdog)
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


def build(loop: LoopLike, out: str | Path, *, only: Sequence[str] | None = None,
          fmus: str = "auto", info: Callable[[str], None] | None = None,
          sets: Sequence[str] | Mapping[str, object] = (), fmi: int = 2,
          clocked: bool = False, platforms: str | Sequence[str] | None = None):
    """Write the FMUs of ``loop`` into the folder ``out``, named after the loop
    (``<name>_plant.fmu``, ``<name>_meas_delay.fmu``, ``<name>_controller.fmu``,
    ``<name>_input_delay.fmu``) with the loop's values as their start values, and
    ``<name>_wiring.txt``: each FMU's inputs and outputs, the connections, T and the base
    step a host must use, and the delays a host provides when it takes only the
    controller. ``delaycomp build LOOP.toml`` on the command line.

    Parameters
    ----------
    loop : Loop, str or Path
        The loop (``load``, ``lti``, ``model``), a loop file's path or a
        scenario's name; its ``name`` names the files.
    out : path
        Output folder (created; files of those names are replaced).
    only : sequence of str, optional
        ``"plant"``, ``"controller"``, ``"delays"``: only these (default: all).
    fmus : str
        As for ``run``: the native C FMUs where they exist (``auto``; the Python ones
        with a note in ``.notes`` otherwise), only native ones, or the Python ones.
    info : callable, optional
        Hears what is being built, one line at a time (the command line's ``-v``).
    sets : sequence of str or mapping, optional
        Overrides, as ``load`` takes them.
    fmi : int, optional
        2 (default) or 3: FMI 3.0 FMUs (native C only, ``delaycomp.fmu.fmi3``: the
        matrices and vectors as arrays sized by structural parameters).
    clocked : bool, optional
        With ``fmi=3``: the controller's clocked variant (its sampling driven by an FMI 3.0
        clock of interval T; LTI controllers).
    platforms : str or sequence of str, optional
        The native FMUs' binaries (``--platforms``): platform tuples (``x86_64-linux``,
        ``aarch64-linux``, ``x86_64-windows``, ``x86_64-darwin``, ``aarch64-darwin``) or
        FMI 2.0 names (``linux64``, ``win64``, ``darwin64``), a list or one
        comma-separated string; default all five (``delaycomp.fmu.toolchain``).

    Returns
    -------
    delaycomp.formats.loopbuild.LoopBuild
        ``.fmus`` (role -> path), ``.wiring``, ``.native``, ``.notes``.

    Examples
    --------
    >>> import tempfile
    >>> from delaycomp import api
    >>> loop = api.lti([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[-1.0, -1.6]], T=0.2,
    ...                r=0.36, tau=0.4, N=20, x0=[1.0, 0.0], name="dbl")
    >>> out = api.build(loop, tempfile.mkdtemp(), only=["controller"], fmus="python")
    >>> sorted(p.name for p in out.paths)
    ['dbl_controller.fmu', 'dbl_wiring.txt']
    """
    from delaycomp.formats.loopbuild import build_loop

    fmi = _fmi_version(fmi, clocked)
    if fmi == 3 and fmus == "python":
        raise ParameterError("fmi = 3 is not allowed with fmus = python: delaycomp's FMI 3.0 "
                             "FMUs are the native C ones")
    if platforms is None:
        return build_loop(_as_loop(loop, sets), out, only=only, fmus=fmus, info=info,
                          fmi=fmi, clocked=clocked)
    from delaycomp.fmu.toolchain import NativeBuildError, chosen, parse_platforms

    text = platforms if isinstance(platforms, str) else ",".join(platforms)
    try:
        names = parse_platforms(text, "platforms")
    except NativeBuildError as exc:
        raise ParameterError(str(exc)) from None
    if not names:
        raise ParameterError("platforms names no platform: give at least one")
    with chosen(names):
        return build_loop(_as_loop(loop, sets), out, only=only, fmus=fmus, info=info,
                          fmi=fmi, clocked=clocked)


def export_c(loop: LoopLike, out: str | Path, prefix: str, *,
             sets: Sequence[str] | Mapping[str, object] = ()) -> list[Path]:
    """Write the controller of ``loop`` as plain C for an embedded target: ``out/prefix.h``
    and ``out/prefix.c`` (C99, no heap, no I/O, no global state), with ``prefix_init``,
    ``prefix_sample`` and ``prefix_output`` (the header documents them and their return
    codes). ``delaycomp export-c LOOP.toml --prefix NAME --out DIR`` on the command line;
    ``docs/howto/microcontroller.md`` shows a firmware loop.

    Parameters
    ----------
    loop : Loop, str or Path
        A loop whose controller is delaycomp's (LTI, or a model file's), a loop file's
        path or a scenario's name.
    out : path
        The folder (created).
    prefix : str
        A C identifier: the files' names and every exported name start with it.
    sets : sequence of str or mapping, optional
        Overrides, as ``load`` takes them.

    Returns
    -------
    list of Path
        ``[out/prefix.h, out/prefix.c]``.

    Examples
    --------
    >>> import tempfile
    >>> from delaycomp import api
    >>> from delaycomp.paper.scenarios import loop_file
    >>> loop = api.load(loop_file("example-3.6"), r=0.4)
    >>> [p.name for p in api.export_c(loop, tempfile.mkdtemp(), "ctl")]
    ['ctl.h', 'ctl.c']
    """
    from delaycomp.formats.exportc import export_c as _export_c

    return _export_c(_as_loop(loop, sets), out, prefix)


def to_ssp(loop: LoopLike, out: str | Path, *, jacobi: bool = False,
           fmu_dir: str | Path | None = None, fmus: str = "auto",
           notes: list[str] | None = None,
           sets: Sequence[str] | Mapping[str, object] = (), fmi: int = 2,
           clocked: bool = False) -> Path:
    """Pack ``loop`` with its FMUs into the SSP archive ``out``; ``jacobi=True`` packs the
    variant that libcosim and Ecos run exactly (see ``delaycomp.system.jacobi``).
    ``fmus`` as for ``run``: the native C FMUs where they exist (``auto``: where they
    do not, the Python ones, and ``notes`` hears why), only native ones, or the Python
    ones. ``delaycomp ssp`` on the command line. ``loop``: a ``Loop``, a loop file's
    path or a scenario's name, with ``sets`` as ``load`` takes them.

    ``fmi=3``: the archive carries FMI 3.0 native FMUs (``clocked``: the controller's
    clocked variant), each with its instance's values as start values (and so a file of
    its own, ``resources/<instance>.fmu``); the SSD and the parameter sets are SSP 1.0 as
    before, the parameter sets with the scalar parameters only (SSP 1.0 knows no arrays:
    ``A``, ``B``, ``K``, ``x0``, ``u0`` are the FMUs' start values)."""
    from delaycomp.formats import ssp
    _fmu_kind(fmus)
    fmi = _fmi_version(fmi, clocked)
    loop = _as_loop(loop, sets)
    fmu_dir = Path(fmu_dir) if fmu_dir else None
    if fmi == 3:
        return _to_ssp3(loop, out, jacobi, fmus, clocked)
    if jacobi:
        from delaycomp.verify.thirdparty import pack_jacobi

        path = pack_jacobi(loop, out, fmu_dir)
    else:
        path = ssp.pack(*ssp.loop_system(loop), out, fmu_dir)
    if fmus != "python":  # the same archive with the native twins of its FMUs
        from delaycomp.fmu.native import NativeBuildError, native_archive

        try:
            native_archive(path, path)
        except (ValueError, NativeBuildError) as exc:  # ModelError is a ValueError
            Path(path).with_name(Path(path).name + ".part").unlink(missing_ok=True)
            if fmus == "native":
                Path(path).unlink()
                raise
            if notes is not None:
                notes.append("the archive holds the Python FMUs (no native ones here: "
                             f"{str(exc).splitlines()[0]})")
    return path


def _to_ssp3(loop: Loop, out: str | Path, jacobi: bool, fmus: str, clocked: bool) -> Path:
    """``to_ssp`` with FMI 3.0 FMUs: built with the loop's values as start values, packed
    beside the same SSD and parameter sets."""
    from delaycomp.formats import ssp
    from delaycomp.formats.loopbuild import native_with_starts
    from delaycomp.tmpfiles import temp_dir

    if fmus == "python":
        raise ParameterError("fmi = 3 is not allowed with fmus = python: delaycomp's FMI 3.0 "
                             "FMUs are the native C ones")
    if jacobi and clocked:
        raise ParameterError("clocked = true is not allowed with jacobi = true: the Jacobi "
                             "variant samples the step before each tick, a clocked controller "
                             "samples at the tick (pack one or the other)")
    spec, info = ssp.loop_system(loop)
    if jacobi:
        from delaycomp.verify.thirdparty import jacobi_variant

        spec, info = jacobi_variant(spec), ssp.jacobi_info(info)
    with temp_dir("delaycomp-ssp3-") as tmp:
        try:
            built = native_with_starts(spec, Path(tmp), fmi=3, clocked=clocked)
        except ValueError as exc:  # no native twin, or no clocked variant
            raise ParameterError(f"{str(exc).splitlines()[0]} (ssp with fmi = 3)") from None
        # SSP 1.0 knows no arrays: the parameter sets hold the scalars, the arrays travel
        # as the FMUs' start values (an element such as A[1,1] names no FMI 3.0 variable)
        scalars = spec.with_instances(
            dataclasses.replace(i, parameters={k: v for k, v in i.parameters.items()
                                               if array_element(k) is None})
            if i.name in built else i for i in spec.instances)
        return ssp.pack(scalars, info, out, fmus=built, own_files=True)


def sweep(source: LoopLike, grid: Mapping[str, Sequence[float]] | Sequence[Axis], *,
          sets: Sequence[str] | Mapping[str, object] = (),
          stop_time: float | None = None, engine: str = "batch", workers: int = 1,
          exact: bool = False, array_backend: str = "numpy", chunk: int | None = None,
          scheduler: str | None = None, notes: list[str] | None = None,
          fmu_dir: str | Path | None = None, verbosity: int = 0) -> list[dict]:
    """Metrics (``rho``, ``stable``, ``final_norm``, ``peak_norm``, ``deadbeat_time``,
    ``failed``) of ``source`` at every point of ``grid`` (parameter name -> values), one
    dict per point in grid order (the last parameter varies fastest). ``failed`` is empty
    where the run reached its stop time, else why not; where that is not the loop's own
    divergence (which is unstable, ``rho = inf``) ``rho`` and ``stable`` are ``None``
    (``delaycomp.studies.sweep``).

    ``source`` is a scenario name, a loop file's path or a ``Loop`` (from
    ``load``, ``lti`` or ``model``: it keeps the loop-file data it was built
    from, and each point is built again from it); grid and ``sets`` names are a scenario's
    parameters or a loop's loop-file keys (``r``, ``T``, ``tau``, ``N``, ``controller.K``,
    ...) or their short names (``x0``, ``u0``, ``K``, ``mode``, a model's own parameters;
    a single number for a vector or matrix key is a list of one: ``K=-2`` is
    ``[[-2]]``). A ``Loop`` sweeps to the rows of the same loop given as a loop file.
    ``engine`` is ``batch`` (all points
    advanced together, vectorized; points it cannot take run on the per-point engine),
    ``inprocess`` or ``fmu`` (point by point); the results agree (tested). ``workers``
    processes or a Dask ``scheduler`` address share the work; ``array_backend`` (numpy,
    cupy, jax, auto) and ``chunk`` (points per batch) tune the batch engine; what it did is
    appended to ``notes``. The ``fmu`` engine takes the FMUs of ``fmu_dir`` first;
    ``verbosity`` 1 shows a progress bar on a terminal. See
    ``delaycomp.studies.sweep.run_sweep``.

    The rows are held together: a grid whose rows would not fit in half of the memory is
    refused before anything runs (a ``ParameterError`` naming the points and the
    estimate); ``iter_sweep`` hands them on one at a time instead.

    Examples
    --------
    Without compensation Example 3.6 loses stability between ``r = 0`` and ``r = 0.5``
    (for ``k = 2``: at ``r_c = 0.203``); at ``r = 0``, ``rho = e - k`` per period:

    >>> notes = []
    >>> rows = sweep("example-3.6", {"k": [1.5, 2.0], "r": [0.0, 0.5]},
    ...              sets=["mode=uncompensated"], stop_time=10.0, notes=notes)
    >>> [(row["k"], row["r"], row["stable"]) for row in rows]
    [(1.5, 0.0, 1), (1.5, 0.5, 0), (2.0, 0.0, 1), (2.0, 0.5, 0)]
    >>> round(rows[2]["rho"], 6)
    0.718282
    >>> notes
    ['batch engine (numpy, cpu): 4 of 4 points in 1 chunk']

    A loop of your own, over its gain and delay:

    >>> loop = lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, x0=[1.0], mode="uncompensated",
    ...            allow_unstable=True)
    >>> rows = sweep(loop, {"K": [-1.5, -2.0], "r": [0.0, 0.5]}, stop_time=10.0)
    >>> [(row["K"], row["r"], row["stable"]) for row in rows]
    [(-1.5, 0.0, 1), (-1.5, 0.5, 0), (-2.0, 0.0, 1), (-2.0, 0.5, 0)]
    """
    from delaycomp.studies.sweep import run_sweep

    return run_sweep(_source(source), _axes(grid), _assignments(sets),
                     _sweep_options(stop_time, engine, workers, scheduler, fmu_dir, exact,
                                    array_backend, chunk, verbosity), notes=notes)


def iter_sweep(source: LoopLike, grid: Mapping[str, Sequence[float]] | Sequence[Axis], *,
               sets: Sequence[str] | Mapping[str, object] = (),
               stop_time: float | None = None, engine: str = "batch", workers: int = 1,
               exact: bool = False, array_backend: str = "numpy", chunk: int | None = None,
               scheduler: str | None = None, notes: list[str] | None = None,
               fmu_dir: str | Path | None = None, verbosity: int = 0) -> Iterator[dict]:
    """``sweep``'s rows one at a time, in grid order, in memory bounded at any grid
    size (``sweep`` holds them all, and refuses a grid whose rows would not fit in half
    of the memory): the points run a stream chunk at a time as the rows are taken. Every
    point is validated before this returns (a refusal raises here); ``notes`` are appended
    once the last row is taken. See ``delaycomp.studies.sweep.iter_sweep``.

    Examples
    --------
    Count the stable points of a map without holding its rows:

    >>> rows = iter_sweep("example-3.6", {"k": [1.5, 2.0], "r": [0.0, 0.5]},
    ...                   sets=["mode=uncompensated"], stop_time=10.0)
    >>> sum(row["stable"] for row in rows)
    2
    """
    from delaycomp.studies.sweep import iter_sweep as stream

    return stream(_source(source), _axes(grid), _assignments(sets),
                  _sweep_options(stop_time, engine, workers, scheduler, fmu_dir, exact,
                                 array_backend, chunk, verbosity), notes=notes)


def _source(source: LoopLike):
    """What a study runs, opened once by the same reading as ``_as_loop``
    (``open_source``: a ``Loop``'s loop-file data, a loop file, a scenario; an opened
    one passes as it is) and handed down opened."""
    from delaycomp.paper.scenarios import open_source

    return open_source(source)  # refuses what is none of them, in one short line


def _sweep_options(stop_time, engine, workers, scheduler, fmu_dir, exact, array_backend,
                   chunk, verbosity):
    """``sweep``'s and ``iter_sweep``'s keywords as the study's ``SweepOptions``."""
    from delaycomp.studies.sweep import SweepOptions

    return SweepOptions(stop=stop_time, engine=engine, workers=workers, scheduler=scheduler,
                        fmu_dir=None if fmu_dir is None else str(fmu_dir), exact=exact,
                        array_backend=array_backend, chunk=chunk, verbosity=verbosity)


def _axes(grid) -> list:
    """The ``Axis`` of each grid parameter: of a mapping of name -> values, or a list of
    ``delaycomp.studies.axes.Axis`` (the command line's ``--grid``, where a name may
    repeat: the sweep refuses that)."""
    from delaycomp.studies.axes import Axis

    if isinstance(grid, (list, tuple)) and grid and all(isinstance(a, Axis) for a in grid):
        items = [(a.name, a.values) for a in grid]
    elif isinstance(grid, Mapping):
        items = list(grid.items())
    else:
        raise ParameterError(f"grid = {short(grid)} is not allowed: give a mapping of "
                             "parameter name -> values")
    axes = []
    for name, values in items:
        try:
            axes.append(Axis(name, tuple(float(v) for v in np.ravel(values))))
        except (TypeError, ValueError):
            raise ParameterError(f"grid[{name!r}] = {short(values)} is not allowed: must "
                                 "be numbers") from None
    return axes


def robustness(loop: LoopLike, jitter: Sequence[float], loss: Sequence[float],
               runs: int, *, seed: int = 0, on: str = "meas_delay",
               modes: Sequence[str] = ("compensated", "uncompensated"),
               distribution: str = "uniform",
               sets: Sequence[str] | Mapping[str, object] = (),
               stop_time: float | None = None, chunk: int | None = None,
               array_backend: str = "numpy", progress: Callable[[int], None] | None = None):
    """A Monte Carlo robustness map of an LTI loop over a network channel's jitter x loss.

    At every ``(jitter, loss)`` the channel ``on`` (its loop-file table the base, else the
    loop's constant delay) draws its delays from ``distribution`` with that amplitude and
    loses packets with that Bernoulli rate; ``runs`` seeds per point and mode run on the
    batch engine (the same numbers as ``run(..., engine="inprocess")`` per seed). See
    ``delaycomp.studies.robustness`` for the seeds and the statistics.

    Parameters
    ----------
    loop : Loop, str or Path
        An LTI loop: a loop file's path or a ``Loop`` built from loop-file data (``lti``,
        ``load``).
    jitter, loss : sequence of float
        The grid: jitter amplitudes [s] (``>= 0``), loss rates (``0 .. 1``).
    runs : int
        Seeds per grid point and mode; run ``i`` draws seed ``seed + i``.
    seed : int
        The base seed (``0 .. 2^31 - 1``).
    on : {"meas_delay", "input_delay"}
        The channel the grid acts on.
    modes : sequence of str
        ``compensated``, ``uncompensated`` (and ``stamped`` once the batch engine reads
        time stamps: ``delaycomp.studies.robustness.stamped_available``).
    distribution : {"uniform", "exponential", "gamma"}
        The jitter's distribution (the latter two need the table's ``max_delay``).
    sets : sequence of str or mapping
        Overrides as ``load`` takes them (``meas_delay.policy=drop_stale``).
    stop_time : float, optional
        Each run's horizon (default: the loop's).
    chunk : int, optional
        Runs per batch-engine call at most.
    array_backend : {"numpy", "cupy", "auto"}
        The batch engine's array library: ``cupy`` runs on an NVIDIA GPU (the ``cupy``
        extra), ``auto`` there where CuPy reaches one, else numpy; the numbers are the
        same bit for bit.
    progress : callable, optional
        ``progress(k)`` hears each ``k`` runs done (a progress bar's update).

    Returns
    -------
    delaycomp.studies.robustness.RobustnessMap
        ``rows``: one dict per grid point and mode (``p_stable`` with its Wilson 95 %
        interval ``p_low``/``p_high``, quantiles of the cost and the final norm);
        ``array(column, mode)`` a column over the grid.

    Examples
    --------
    Example 3.6 with its measurement through a lossy, jittery network (delays from
    ``r = 0.3`` to ``0.5``): the predictor keeps every run stable, the feedback on the
    late sample alone none:

    >>> m = robustness(lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, x0=[1.0]),
    ...                jitter=[0.0, 0.2], loss=[0.0, 0.3], runs=50, stop_time=20.0)
    >>> m.array("p_stable", "compensated").tolist()
    [[1.0, 1.0], [1.0, 1.0]]
    >>> [row["stable"] for row in m.rows if row["mode"] == "uncompensated"]
    [0, 0, 0, 0]
    """
    from delaycomp.studies import robustness as study
    from delaycomp.system.loopfile import LoopFile

    source = _source(loop)
    if not isinstance(source, LoopFile):
        raise ParameterError(f"loop = {short(loop)} is not allowed: give an LTI loop file's "
                             "path or a Loop built from loop-file data (a scenario: its "
                             "loop file, delaycomp.paper.scenarios.loop_file)")
    return study.robustness(source, jitter, loss, runs, seed=seed, on=on, modes=modes,
                            distribution=distribution, sets=_assignments(sets),
                            stop_time=stop_time, chunk=chunk, array_backend=array_backend,
                            progress=progress)


def critical_delay(loop: LoopLike, *,
                   sets: Sequence[str] | Mapping[str, object] = ()) -> float:
    """The largest measurement delay ``r_c`` for which the *uncompensated* LTI loop is
    stable, from the spectral radius of the exact lifted model (the loop's own ``r`` is not
    used). ``loop``: a ``Loop``, a loop file's path or a scenario's name, with
    ``sets`` as ``load`` takes them.

    Examples
    --------
    Example 3.6 with ``k = 2`` (``r_c = 0.203``, see ``sweep``):

    >>> round(critical_delay("example-3.6", sets={"k": 2.0}), 3)
    0.203
    """
    from delaycomp.maths.lti import critical_delay as search
    from delaycomp.maths.lti import lifted_loop

    loop = _as_loop(loop, sets)
    refuse_channel(loop, "critical_delay (its lifted model has constant delays)")
    d = loop.lti
    if d is None:
        raise ParameterError(f"critical_delay needs an LTI loop; {loop.name} is not")
    d = d.equivalent(loop.T)  # pad: the loop of the padded delay

    def rho(r: float) -> float:
        return lifted_loop(d.A, d.B, d.K, loop.T, r, d.tau, "uncompensated").spectral_radius

    return search(rho, r_max=50 * loop.T, step=loop.T / 100)


def critical_delay_report(loop: LoopLike, *,
                          sets: Sequence[str] | Mapping[str, object] = (),
                          periods: int = 40, fmu_dir: str | Path | None = None):
    """``critical_delay``'s ``r_c``, confirmed by co-simulation (``delaycomp
    critical-delay``): the uncompensated loop runs ``periods`` periods just below and just
    above ``r_c`` on its FMUs (those of ``fmu_dir`` first), and the spectral radius fitted
    to each trajectory must fall on the side the lifted model says.

    Returns
    -------
    delaycomp.studies.critical.CriticalDelayReport
        ``r_c``, ``confirmed``, ``checks`` (``r``, the lifted model's spectral radius,
        the fitted one) and the report's ``lines``.

    Examples
    --------
    >>> report = critical_delay_report("example-3.6", sets={"k": 2.0}, periods=10)
    >>> round(report.r_c, 3), report.confirmed
    (0.203, True)
    """
    from delaycomp.studies.critical import critical_delay_report as report

    if isinstance(periods, bool) or not isinstance(periods, int) or periods < 10:
        raise ParameterError(f"periods = {periods!r} is not allowed: must be an integer >= 10")
    return report(_source(loop), _assignments(sets), periods,
                  None if fmu_dir is None else Path(fmu_dir))


def critical_delay_table(loop: LoopLike, grid: str, *,
                         sets: Sequence[str] | Mapping[str, object] = (),
                         out: str | Path | None = None,
                         plot: str | Path | None = None) -> list[str]:
    """``r_c`` of the uncompensated and of the compensated loop along one parameter
    (``grid``: ``NAME=START:STOP:COUNT``), from the exact lifted model alone (``delaycomp
    critical-delay --grid``); the table written as CSV to ``out`` and drawn to ``plot``
    where given. Returns the table's text lines (a header, then one line per value;
    ``stable r<=R`` where no ``r`` up to the search's end loses stability, ``unstable at
    r=0`` where ``r = 0`` already does). See ``delaycomp.studies.critical``.

    Examples
    --------
    >>> for line in critical_delay_table("example-3.6", "k=1.5:2:2"):
    ...     print(line)
             k  r_c uncompensated    r_c compensated
           1.5        0.281372633        stable r<=5
             2        0.203267055        stable r<=5
    """
    from delaycomp.studies.critical import critical_delay_table as table

    return table(_source(loop), _assignments(sets), grid,
                 None if out is None else Path(out), None if plot is None else Path(plot))
