"""Run a :class:`~delaycomp.scenarios.LoopSpec` with the project's FMUs and master."""

from __future__ import annotations

import csv
import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import delaycomp
from orchestrator.fmu import FmuComponent
from orchestrator.master import Connection, Master, Recorder, SimulationError

from .build import BUNDLED_MODULES, DEFAULT_CONFIG, FMUS, PACKAGE_DIR, build_fmu, model_identifier
from .scenarios import LoopSpec, ParameterError, on_grid

__all__ = ["Result", "SimulationError", "default_fmu_dir", "fmu_path", "run_loop"]


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
    """Path of the FMU for ``kind`` and ``config`` in ``fmu_dir``; built there if missing."""
    fmu_dir = Path(fmu_dir) if fmu_dir is not None else default_fmu_dir()
    path = fmu_dir / fmu_file_name(kind, config)
    if not path.exists():
        build_fmu(kind, fmu_dir, config, path.name)
    return path


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

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.names.index(name)]

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
    h = T / N
    if not (math.isfinite(stop_time) and stop_time > 0):
        raise ParameterError(f"--stop-time {stop_time!r} is not allowed: must be a finite "
                             "number > 0")
    if not on_grid(stop_time, h):
        raise ParameterError(f"--stop-time {stop_time!r} is not allowed: must be a multiple "
                             f"of the base step h = T/N = {h!r}")
    return round(stop_time / h)


def run_loop(spec: LoopSpec, stop_time: float, fmu_dir: Path | None = None,
             t0: float = 0.0, fmus: dict[str, Path] | None = None) -> Result:
    """Co-simulate ``spec`` from ``t0`` to ``stop_time`` with one row per base step.

    ``fmus`` gives the FMU file of some instances (e.g. from an SSP archive); the others
    come from :func:`fmu_path`. On a component failure the result so far is returned with
    ``success=False`` and the failure in ``message``.
    """
    ticks = stop_ticks(stop_time - t0, spec.T, spec.N)
    fmus = fmus or {}
    components = [FmuComponent(name, fmus.get(name) or fmu_path(kind, config, fmu_dir))
                  for name, (kind, config, _) in spec.instances.items()]
    master = Master(components, [Connection.parse(c) for c in spec.connections],
                    spec.T, spec.N, t0)
    recorder = Recorder(master, spec.recorded)
    master.add_observer(recorder)
    success, message = True, ""
    try:
        master.setup(stop_time, {name: params for name, (_, _, params)
                                 in spec.instances.items()})
        master.initialize()
        master.run_until(ticks)
    except SimulationError as exc:
        success, message = False, str(exc)
    finally:
        master.terminate()
    data = np.array(recorder.rows, dtype=float).reshape(len(recorder.rows), len(spec.recorded))
    notes = [f"{c.name}: {m.split('] ', 1)[1]}" for c in components
             for m in getattr(c, "messages", ()) if m.startswith(("[ok]", "[warning]"))]
    return Result(recorder.names, np.array(recorder.times), data, success, message, notes)
