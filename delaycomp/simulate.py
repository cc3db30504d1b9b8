"""Run a :class:`~delaycomp.system.Loop` with the project's FMUs and master.

:func:`make_master` is the one function that wires a master from a loop; everything that
runs a loop (``run``, sweeps, the cross-check, the benchmark) goes through it.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import json
import os
import stat
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import delaycomp
from delaycomp.orchestrator.fmu import FmuComponent
from delaycomp.orchestrator.master import Connection, Master, Recorder, SimulationError

from .build import (
    BUNDLED_MODULES,
    CONFIG_NAME,
    DEFAULT_CONFIG,
    FMUS,
    PACKAGE_DIR,
    build_fmu,
    model_identifier,
)
from .errors import BadFileError, ParameterError
from .system import FmuFile, Loop, Timing
from .tmpfiles import build_lock

__all__ = ["ENGINES", "Result", "SimulationError", "default_fmu_dir", "fmu_path",
           "make_components", "make_master", "parameters_of", "run_loop", "source_fmu"]


def _source_digest() -> str:
    """Digest of everything that goes into an FMU, naming the build cache."""
    h = hashlib.sha256(delaycomp.__version__.encode())
    files = [PACKAGE_DIR / m for m in BUNDLED_MODULES]
    for spec in FMUS.values():
        files += [spec.script_path, spec.folder / "README.md"]
    for f in files:
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def default_fmu_dir() -> Path:
    """Build cache: ``$DELAYCOMP_CACHE_DIR`` or ``~/.cache/delaycomp``, per source digest."""
    root = os.environ.get("DELAYCOMP_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "delaycomp")
    return Path(root) / f"fmus-{delaycomp.__version__}-{_source_digest()}"


def fmu_file_name(kind: str, config: dict) -> str:
    """``<ModelIdentifier>.fmu`` for the default dimensions, else with the config in it."""
    ident = model_identifier(kind, config)
    if FMUS[kind].template or config == DEFAULT_CONFIG[kind]:
        return f"{ident}.fmu"
    tag = "_".join(f"{k}{config[k]}" for k in sorted(config))
    return f"{ident}_{tag}.fmu"


def fmu_path(kind: str, config: dict, fmu_dir: Path | None = None) -> Path:
    """Path of the FMU for ``kind`` and ``config`` in ``fmu_dir``; built there if missing.

    An FMU already there is checked first (:func:`check_fmu`): a corrupt or foreign file
    raises :class:`~delaycomp.errors.BadFileError` before anything runs.
    """
    fmu_dir = Path(fmu_dir) if fmu_dir is not None else default_fmu_dir()
    if fmu_dir.exists() and not fmu_dir.is_dir():
        raise BadFileError(fmu_dir, "is not a folder (--fmu-dir wants a folder of FMUs)")
    path = fmu_dir / fmu_file_name(kind, config)
    _regular_or_missing(path)
    if not path.exists():
        fmu_dir.mkdir(parents=True, exist_ok=True)
        with build_lock(path):  # parallel first runs: one builds, the others wait
            if not path.exists():
                build_fmu(kind, fmu_dir, config, path.name)
    check_fmu(path, kind, config)
    return path


def _regular_or_missing(path: Path) -> None:
    """Refuse a link, a FIFO, a device or a folder where an FMU file belongs: reading one
    could hang (a FIFO) or never end (``/dev/zero``), and building through a link would
    write outside the folder."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise BadFileError(path, f"cannot be read: {exc.strerror}") from None
    if stat.S_ISLNK(mode):
        raise BadFileError(path, "is a symbolic link: FMUs in --fmu-dir must be regular "
                                 "files (copy the file there)")
    if not stat.S_ISREG(mode):
        raise BadFileError(path, "is not a regular file: FMUs in --fmu-dir must be regular "
                                 "files")


#: FMU files already checked in this process, with their modification time and size
_CHECKED: set[tuple] = set()


def check_fmu(path: Path, kind: str, config: dict) -> None:
    """Refuse an FMU that is not a zip, has no readable modelDescription, is of another
    model, or was built for other dimensions or another delaycomp version. A file checked
    before and unchanged since is not read again (runs of a sweep look up the same FMUs)."""
    try:
        st = Path(path).stat()
        key = (str(path), st.st_mtime_ns, st.st_size, kind,
               json.dumps(config, sort_keys=True, default=str))
    except OSError:
        key = None
    if key is not None and key in _CHECKED:
        return
    _regular_or_missing(Path(path))
    _check_fmu(path, kind, config)
    if key is not None:
        _CHECKED.add(key)


def _check_fmu(path: Path, kind: str, config: dict) -> None:
    from fmpy import read_model_description

    ident = model_identifier(kind, config)
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            if "modelDescription.xml" not in names:
                raise BadFileError(path, "is not an FMU: it has no modelDescription.xml")
            built = zf.read(f"resources/{CONFIG_NAME}") if (
                f"resources/{CONFIG_NAME}" in names) else None
        md = read_model_description(str(path), validate=False)
    except BadFileError:
        raise
    except zipfile.BadZipFile:
        raise BadFileError(path, "is not an FMU: not a zip archive") from None
    except Exception as exc:  # noqa: BLE001 - any parse failure is a bad file
        raise BadFileError(path, f"is not a readable FMU: {type(exc).__name__}: {exc}"
                           ) from None
    found = md.coSimulation.modelIdentifier if md.coSimulation else None
    if found != ident:
        what = f"model {found!r}" if found else "a model without co-simulation"
        raise BadFileError(path, f"is an FMU of {what}, expected {ident!r} (delete it or use "
                                 "another --fmu-dir to rebuild)")
    if built is None:
        raise BadFileError(path, f"is not a delaycomp FMU: no resources/{CONFIG_NAME}")
    try:
        cfg = json.loads(built)
    except ValueError:
        raise BadFileError(path, f"has a corrupt resources/{CONFIG_NAME}") from None
    if cfg.get("version") != delaycomp.__version__:
        raise BadFileError(path, f"was built by delaycomp {cfg.get('version')!r}, this is "
                                 f"{delaycomp.__version__!r} (delete it to rebuild)")
    wanted = {k: v for k, v in config.items() if k != "model"}
    differs = {k: cfg.get(k) for k, v in wanted.items() if cfg.get(k) != v}
    if differs:
        raise BadFileError(path, f"was built for {differs}, this loop needs "
                                 f"{ {k: wanted[k] for k in differs} }")


@dataclass
class Result:
    """Recorded signals: ``data[k, j]`` is signal ``names[j]`` at ``times[k]``."""

    names: list[str]
    times: np.ndarray
    data: np.ndarray
    success: bool = True
    message: str = ""
    #: informational messages the components logged, as ``instance: text``
    notes: list[str] = field(default_factory=list)
    #: rows recorded (streamed to a sink, or kept here); ``None``: ``len(times)``
    rows: int | None = None

    @property
    def row_count(self) -> int:
        """Rows recorded in the run (more than :attr:`times` holds if the run streamed)."""
        return len(self.times) if self.rows is None else self.rows

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.names.index(name)]

    def __getitem__(self, name: str) -> np.ndarray:
        """The signal ``name`` (``"plant.x1"``, ``"controller.u"``) as an array."""
        if name not in self.names:
            raise KeyError(f"no signal {name!r}: the run recorded {', '.join(self.names)}")
        return self.column(name)

    @property
    def signals(self) -> dict[str, np.ndarray]:
        """Every recorded signal by name, one array each (``times`` is the time axis)."""
        return {name: self.data[:, j] for j, name in enumerate(self.names)}

    def to_pandas(self):
        """A ``pandas.DataFrame`` indexed by time, one column per signal (needs pandas)."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("to_pandas() needs pandas: pip install pandas") from None
        return pd.DataFrame(self.data, index=pd.Index(self.times, name="time"),
                            columns=list(self.names))

    def write_csv(self, path: str | Path) -> None:
        path = Path(path)
        tmp = path.with_name(path.name + ".part")
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["time", *self.names])
            for t, row in zip(self.times, self.data):
                w.writerow([repr(float(t)), *(repr(float(v)) for v in row)])
        tmp.replace(path)  # no half-written file that looks like a result


def stop_ticks(stop_time: float, T: float, N: int) -> int:
    """Base steps to ``stop_time`` (:meth:`delaycomp.system.Timing.ticks`)."""
    return Timing(T, N).ticks(stop_time)


#: ``fmu``: the built FMUs through fmpy; ``inprocess``: the same slave classes called
#: directly (:mod:`orchestrator.inprocess`), same master, same numbers, much faster.
ENGINES = ("fmu", "inprocess")


def source_fmu(source, fmu_dir: Path | None = None) -> Path:
    """The FMU file of an instance's source: a given file as it is, else the built FMU of
    its kind and configuration (:func:`fmu_path`)."""
    if isinstance(source, FmuFile):
        return Path(source.path)
    return fmu_path(*source.build_key(), fmu_dir)


def make_components(loop: Loop, engine: str = "fmu", fmu_dir: Path | None = None,
                    fp_guarded: bool = False, fmus: dict[str, Path] | None = None) -> list:
    """The master components of ``loop`` for ``engine``. ``fp_guarded`` (in-process only):
    the caller steps them under ``np.errstate(all="ignore")``. ``fmus`` (FMU engine only)
    gives the FMU file of some instances (e.g. from an SSP archive); the others come from
    :func:`source_fmu`."""
    if engine == "fmu":
        fmus = fmus or {}
        return [FmuComponent(i.name, fmus.get(i.name) or source_fmu(i.source, fmu_dir))
                for i in loop.instances]
    if fmus:
        raise ParameterError("FMU files are not allowed with the in-process engine")
    if engine == "inprocess":
        from delaycomp.orchestrator.inprocess import SlaveComponent

        files = [i.name for i in loop.instances if isinstance(i.source, FmuFile)]
        if files:
            raise ParameterError(f"instance {files[0]} is an FMU file: the in-process "
                                 "engine runs delaycomp's own slaves only (use --engine fmu)")
        return [SlaveComponent(i.name, *i.source.build_key(), fp_guarded)
                for i in loop.instances]
    raise ParameterError(f"engine {engine!r} is not allowed: must be one of "
                         f"{', '.join(ENGINES)}")


def make_master(loop: Loop, fmu_dir: Path | None = None, t0: float = 0.0,
                every: int = 1, engine: str = "fmu", fp_guarded: bool = False,
                fmus: dict[str, Path] | None = None,
                components: list | None = None, sink=None, keep: bool = True,
                final: int | None = None) -> tuple[Master, Recorder]:
    """The master of ``loop``: its components (fresh ones for ``engine``, or the given
    ``components``, e.g. wrapped to tap their signals), its connections, its timing, and a
    recorder of its recorded ports at every ``every``-th tick and at tick ``final``
    (``sink`` and ``keep`` as in :class:`~delaycomp.orchestrator.master.Recorder`). Not yet
    set up: call ``master.setup(stop_time, loop.parameters())``."""
    if components is None:
        components = make_components(loop, engine, fmu_dir, fp_guarded, fmus)
    connections = [Connection(c.src.instance, c.src.variable, c.dst.instance, c.dst.variable)
                   for c in loop.connections]
    try:
        master = Master(components, connections, loop.T, loop.N, t0)
    except ValueError as exc:  # an algebraic loop, named by its members: a loop to fix
        for c in components:
            if hasattr(c, "terminate") and getattr(c, "fmu", None) is not None:
                c.terminate()
        raise ParameterError(f"loop {loop.name}: {exc}") from None
    recorder = Recorder(master, [(p.instance, p.variable) for p in loop.recorded], every,
                        sink, keep, final)
    master.add_observer(recorder)
    return master, recorder


def parameters_of(loop: Loop) -> dict[str, dict]:
    return loop.parameters()


def run_loop(loop: Loop, stop_time: float, fmu_dir: Path | None = None,
             t0: float = 0.0, engine: str = "fmu",
             fmus: dict[str, Path] | None = None, every: int = 1, sink=None,
             keep: bool = True, progress=None) -> Result:
    """Co-simulate ``loop`` from ``t0`` to ``stop_time``.

    Parameters
    ----------
    loop : Loop
        the loop.
    stop_time, t0 : float
        the interval; ``stop_time - t0`` must be a multiple of the base step.
    fmu_dir : Path, optional
        folder of built FMUs (default: the per-version cache).
    engine : str
        ``fmu`` (the FMUs through fmpy) or ``inprocess`` (the same slaves without the FMI
        layer).
    fmus : dict, optional
        the FMU file of some instances (e.g. from an SSP archive); the others come from
        :func:`source_fmu`.
    every : int
        record every ``every``-th base step (and the stop time); 1: every base step.
    sink : callable, optional
        ``sink(t, row)`` receives every recorded row as the run goes (a streamed CSV).
    keep : bool
        keep the recorded rows in the result; ``False`` keeps only the last one (memory
        stays flat however long the run).
    progress : callable, optional
        ``progress(ticks_done)`` called about every 1 % of the run.

    Returns
    -------
    Result
        On a component failure the result so far, with ``success=False`` and the failure
        in ``message``.
    """
    ticks = loop.timing.ticks(stop_time - t0)
    return _run(loop, ticks, stop_time, fmu_dir, t0, engine, fmus, every, sink, keep,
                progress)


def single_threaded_blas():
    """Context in which BLAS/LAPACK run on one thread.

    The loop's matrices are tiny (n, m <= 12): a BLAS thread pool only adds hand-offs,
    and on a loaded machine those cost more than the maths (measured: a sweep point of
    Example 3.6 took 2.5 times longer with OpenBLAS's default threads on 2 busy cores).
    The previous limits are restored on exit.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _run(spec: Loop, ticks: int, stop_time: float, fmu_dir, t0: float,
         engine: str, fmus: dict[str, Path] | None, every: int = 1, sink=None,
         keep: bool = True, progress=None) -> Result:
    # In-process, the slaves' floating-point guard is set once for the run, not per step
    # (the FMUs keep their own: their host's numpy settings are not ours to assume).
    guard = engine == "inprocess"
    master, recorder = make_master(spec, fmu_dir, t0, every, engine=engine,
                                   fp_guarded=guard, fmus=fmus, sink=sink, keep=keep,
                                   final=ticks)
    components = list(master.components.values())
    success, message = True, ""
    with contextlib.ExitStack() as stack:
        # BLAS on one thread where Python maths runs in this process (the in-process
        # slaves, pythonfmu FMUs); a loop of native FMUs does not pay for threadpoolctl
        if any(getattr(c, "runs_python", True) for c in components):
            stack.enter_context(single_threaded_blas())
        try:
            master.setup(stop_time, spec.parameters())
            master.initialize()
            if guard:
                with np.errstate(all="ignore"):
                    _run_until(master, ticks, progress)
            else:
                _run_until(master, ticks, progress)
        except SimulationError as exc:
            success, message = False, str(exc)
        finally:
            master.terminate()
    data = np.array(recorder.rows, dtype=float).reshape(len(recorder.rows), len(spec.recorded))
    notes = [f"{c.name}: {m.split('] ', 1)[1]}" for c in components
             for m in getattr(c, "messages", ()) if m.startswith(("[ok]", "[warning]"))]
    return Result(recorder.names, np.array(recorder.times), data, success, message, notes,
                  recorder.count)


def _run_until(master: Master, ticks: int, progress) -> None:
    """``master.run_until(ticks)``, in about a hundred chunks when ``progress`` is given."""
    if progress is None:
        master.run_until(ticks)
        return
    chunk = max(1, ticks // 100)
    while master.k < ticks:
        master.run_until(min(ticks, master.k + chunk))
        progress(master.k)
