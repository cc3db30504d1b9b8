"""Run an ``.ssp`` in OMSimulator, OpenModelica's FMI and SSP co-simulation engine.

Two ways in, both found by ``locate``:

- the **Python API** (``from OMSimulator import SSP``): ``run_ssp`` loads the archive
  unchanged, sets the base step ``h`` as the fixed step, steps to each ``t_k = t0 + k h``
  and reads the recorded signals as doubles (so no 12-digit CSV limits the comparison);
- the **command line** (``bin/OMSimulator --stopTime=S --resultFile=F file.ssp``), which
  reads the step size from the archive's ``org.openmodelica`` annotation
  (``delaycomp.formats.ssp``); ``cli_command`` gives its argv and environment, with the
  three settings a pythonfmu FMU needs in a host that is not Python (``cli_env``).

OMSimulator's fixed-step master orders the direct-feedthrough chain itself, so the plain
archive is exact there; the Jacobi variant (``delaycomp ssp --jacobi``) runs to the same
trajectory too. When an FMU discards a step OMSimulator stops there and its command line
still exits 0: ``run_ssp`` compares the time reached after every step with ``t_k`` and
reports the last error OMSimulator logged.

The OMSimulator package is searched in the folder named by ``DELAYCOMP_OMSIMULATOR`` (an
install folder with ``bin/OMSimulator`` and ``lib/x86_64-linux-gnu/OMSimulator/``), else as
the importable ``OMSimulator`` package (``pip install OMSimulator``, which needs internet
while it installs). Each run happens in a fresh Python process, as for libcosim and Ecos
(``delaycomp.verify.thirdparty``).
"""

from __future__ import annotations

import ctypes
import importlib.util
import json
import math
import os
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from delaycomp.child import module_argv
from delaycomp.errors import DelaycompError
from delaycomp.orchestrator.simulate import Result

#: the environment variable that names an OMSimulator install folder
ENV = "DELAYCOMP_OMSIMULATOR"
#: where the Python package and the command line lie in an install folder
PACKAGE_SUBDIR = Path("lib") / "x86_64-linux-gnu"
CLI_SUBPATH = Path("bin") / "OMSimulator"
INSTALL_HINT = (f"pip install OMSimulator (it downloads its binaries while it installs), "
                f"or set {ENV} to an install folder holding {CLI_SUBPATH.as_posix()} and "
                f"{PACKAGE_SUBDIR.as_posix()}/OMSimulator/")


class NotInstalled(DelaycompError, RuntimeError):
    """OMSimulator was not found (one-line message with the install hint)."""


@dataclass(frozen=True)
class Install:
    """Where OMSimulator was found."""

    #: folder to put first on ``sys.path`` (None: ``OMSimulator`` imports as it is)
    package_dir: Path | None
    #: the command line, when known (an install folder has it; a pip install may not)
    cli: Path | None


def locate() -> Install:
    """OMSimulator from ``$DELAYCOMP_OMSIMULATOR``, else the ``OMSimulator`` package.

    Raises
    ------
    NotInstalled
        Neither is there; a ``DELAYCOMP_OMSIMULATOR`` that names a folder without the
        package is an error of its own (not a silent fallback).
    """
    folder = os.environ.get(ENV)
    if folder:
        root = Path(folder).expanduser().resolve()
        pkg = root / PACKAGE_SUBDIR
        if not (pkg / "OMSimulator" / "__init__.py").is_file():
            raise NotInstalled(f"{ENV}={folder} holds no {PACKAGE_SUBDIR.as_posix()}/"
                               "OMSimulator/ (it must name an OMSimulator install folder)")
        cli_path = root / CLI_SUBPATH
        return Install(pkg, cli_path if cli_path.is_file() else None)
    spec = importlib.util.find_spec("OMSimulator")
    if spec is None or spec.origin is None:
        raise NotInstalled(f"OMSimulator is not installed: {INSTALL_HINT}")
    # pip's package ships the command line in its own folder (bin/ or beside the module)
    here = Path(spec.origin).parent
    cli = next((p for p in (here / "bin" / "OMSimulator", here / "OMSimulator")
                if p.is_file()), None)
    return Install(None, cli)


# -- the Python API --------------------------------------------------------------------------

def run_ssp(ssp_path: str | Path, stop_time: float, timeout: float = 900.0) -> Result:
    """Run ``ssp_path`` in OMSimulator's Python API from 0 to ``stop_time``, in a fresh
    process; one row per base step and the columns the SSD records, as our master's.

    A run that stops before ``stop_time`` is a failed
    ``Result`` whose message is OMSimulator's last
    logged error. Raises ``NotInstalled`` when OMSimulator is absent.
    """
    install = locate()
    if _holds_fmi3(ssp_path):
        return _run_cli(ssp_path, stop_time, timeout)
    with tempfile.TemporaryDirectory(prefix="delaycomp-oms-") as tmp:
        out = Path(tmp) / "result.npz"
        proc = subprocess.run(
            module_argv("delaycomp.verify.omsimulator", str(Path(ssp_path).resolve()),
                        repr(float(stop_time)), str(out), str(install.package_dir or "")),
            capture_output=True, text=True, timeout=timeout, cwd=tmp)
        if not out.exists():
            lines = [ln for ln in (proc.stderr + proc.stdout).strip().splitlines()
                     if ln.strip()]
            errors = [ln for ln in lines if ln.lstrip().startswith("error:")]
            reason = (errors or lines or [f"exit status {proc.returncode}"])[-1].strip()
            return Result([], np.zeros(0), np.zeros((0, 0)), False, f"omsimulator: {reason}")
        with np.load(out) as z:
            return Result(json.loads(str(z["names"])), z["times"], z["data"],
                          bool(z["success"]), str(z["message"])).checked_finite("omsimulator")


def _holds_fmi3(ssp_path: str | Path) -> bool:
    """Does the archive hold an FMI 3.0 FMU (``delaycomp ssp --fmi 3``)?"""
    import zipfile

    with zipfile.ZipFile(ssp_path) as outer:
        for name in outer.namelist():
            if name.startswith("resources/") and name.endswith(".fmu"):
                with outer.open(name) as raw, zipfile.ZipFile(raw) as fmu:
                    if b'fmiVersion="3.0"' in fmu.read("modelDescription.xml")[:400]:
                        return True
    return False


def _run_cli(ssp_path: str | Path, stop_time: float, timeout: float) -> Result:
    """``run_ssp`` through the command line, for archives of FMI 3.0 FMUs: OMSimulator's
    Python API cannot read them (3.0.0-111: ``KeyError: 'structuralParameter'`` in its
    ``fmu.py``), its command line runs them. Its CSV keeps 12 significant digits; a run
    that logs an error, or ends before ``stop_time``, is a failed ``Result``."""
    from lxml import etree

    from delaycomp.formats.ssp import NSMAP, SSD_NAME, Archive

    with Archive(ssp_path) as archive:
        assert archive.system is not None and archive.folder is not None
        spec = archive.system.spec
        jacobi = "Jacobi variant" in archive.system.info.description
        system = etree.parse(str(archive.folder / SSD_NAME)).getroot().find(
            "ssd:System", NSMAP).get("name")
    with tempfile.TemporaryDirectory(prefix="delaycomp-oms-") as tmp:
        result = Path(tmp) / "result.csv"
        argv, env = cli_command(Path(ssp_path).resolve(), stop_time, result)
        proc = subprocess.run(argv, env=env, capture_output=True, text=True,
                              timeout=timeout, cwd=tmp)
        errors = [ln for ln in (proc.stdout + proc.stderr).splitlines()
                  if ln.startswith("error:")]
        if errors or not result.exists():
            reason = (errors or [f"exit status {proc.returncode}, no result"])[0]
            return Result([], np.zeros(0), np.zeros((0, 0)), False, f"omsimulator: {reason}")
        times, data = read_cli_result(result, system, spec.recorded)
    ok = bool(len(times)) and math.isclose(times[-1], stop_time, rel_tol=0, abs_tol=1e-9)
    res = Result(list(spec.columns), times, data, ok,
                 "" if ok else f"omsimulator: the run stopped at t = {times[-1]!r}"
                 ).checked_finite("omsimulator")
    if not jacobi:
        res.notes.append(JACOBI_FMI3_NOTE)
    return res


#: what OMSimulator does with a plain archive of FMI 3.0 FMUs (measured, 3.0.0-111: it
#: reads an FMI 3.0 output's dependencies, value references, as FMI 2.0 indices into the
#: variable list, so its order of the direct-feedthrough chain is not the loop's)
JACOBI_FMI3_NOTE = (
    "OMSimulator does not order FMI 3.0 FMUs by their direct feedthrough (the plain archive "
    "of Example 3.6: 5.3e-3 off our master, its Jacobi variant within 5e-12): for the "
    "loop's exact trajectory pack it with `delaycomp ssp --jacobi --fmi 3`")


def _logged_error(log: Path) -> str:
    """The first error OMSimulator logged (the cause; later ones repeat it), without its
    time stamp."""
    try:
        lines = log.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return ""
    for line in lines:
        text = line.split(" | ", 1)[-1].strip()
        if text.startswith("error:"):
            return text
    return ""


def _worker(ssp_path: str, stop_time: float, out: str, package_dir: str) -> None:
    from lxml import etree

    from delaycomp.formats.ssp import NSMAP, SSD_NAME, Archive
    from delaycomp.orchestrator.simulate import stop_ticks

    if package_dir:
        sys.path.insert(0, package_dir)
    from OMSimulator import SSP, Capi, CRef
    from OMSimulator.capi import Status

    with Archive(ssp_path) as archive:
        assert archive.system is not None and archive.folder is not None  # by __enter__
        spec = archive.system.spec
        system = etree.parse(str(archive.folder / SSD_NAME)).getroot().find(
            "ssd:System", NSMAP).get("name")
    h = spec.T / spec.N
    ticks = stop_ticks(stop_time, spec.T, spec.N)
    log = Path(out).with_suffix(".log")
    Capi.setLogFile(str(log))
    model = SSP(ssp_path).instantiate()
    name = model.modelName
    model.setResultFile("")
    model.setFixedStepSize(h)
    model.setStopTime(float(stop_time))
    refs = [CRef(system, port.instance, port.variable) for port in spec.recorded]
    k = np.arange(ticks + 1)
    grid = (k // spec.N) * spec.T + (k % spec.N) * h  # the times of our master
    rows, message = [], ""
    now = ctypes.c_double()
    get_time = Capi.obj.oms_getTime
    get_time.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_double)]
    get_time.restype = ctypes.c_int
    try:
        model.initialize()
        rows.append([model.getValue(r) for r in refs])
        for tk in grid[1:]:
            # OMSimulator adds h to its time (t += h: 3.3e-13 s behind or ahead at t = 20
            # with h = 0.01, measured) and steps while its time is below the target: a
            # target of t_k itself can take one step too many, t_k - h/2 takes one step
            status = Capi.stepUntil(name, float(tk - h / 2))
            get_time(name.encode(), ctypes.byref(now))
            if status not in (Status.ok, Status.warning) or not math.isclose(
                    now.value, tk, rel_tol=0, abs_tol=1e-6 * h):
                message = (f"omsimulator: the run stopped at t = {now.value!r} before "
                           f"t = {float(tk)!r} (status {status.name}): "
                           f"{_logged_error(log) or 'no error logged'}")
                break
            rows.append([model.getValue(r) for r in refs])
    except RuntimeError as exc:  # the Python API raises on a non-ok status
        message = f"omsimulator: {exc}: {_logged_error(log) or 'no error logged'}"
    data = np.array(rows, dtype=float).reshape(len(rows), len(refs))
    np.savez(out, names=json.dumps(spec.columns),
             times=grid[:len(rows)], data=data, success=not message, message=message)


if __name__ == "__main__":  # the per-run process
    _worker(sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4])
    # leave without tearing down OMSimulator and the pythonfmu runtime it loaded (see
    # delaycomp.verify.thirdparty)
    sys.stdout.flush()
    os._exit(0)


# -- the command line ----------------------------------------------------------------------

def cli_env(base: dict | None = None) -> dict[str, str]:
    """The environment in which a host that is not Python (OMSimulator's command line)
    loads this interpreter's pythonfmu FMUs: ``LD_PRELOAD`` of its ``libpython``,
    ``PYTHONHOME`` of its build and ``PYTHONPATH`` to its site-packages (numpy, scipy; the
    FMUs bundle ``delaycomp``). Raises ``RuntimeError`` for a Python without a shared
    ``libpython``."""
    env = dict(os.environ if base is None else base)
    lib = Path(sysconfig.get_config_var("LIBDIR") or "") / (
        sysconfig.get_config_var("LDLIBRARY") or "")
    if not lib.is_file() or ".so" not in lib.name:
        raise RuntimeError(f"this Python has no shared libpython ({lib}): pythonfmu FMUs "
                           "cannot run in a host that is not Python")
    paths = dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    env.update(LD_PRELOAD=str(lib), PYTHONHOME=sys.base_prefix,
               PYTHONPATH=os.pathsep.join(paths))
    return env


def cli_command(ssp_path: str | Path, stop_time: float, result_file: str | Path
                ) -> tuple[list[str], dict[str, str]]:
    """argv and environment of OMSimulator's command line running ``ssp_path`` to
    ``stop_time`` into ``result_file`` (CSV). Raises ``NotInstalled`` without it."""
    install = locate()
    if install.cli is None:
        raise NotInstalled(f"OMSimulator's command line was not found: {INSTALL_HINT}")
    return ([str(install.cli), f"--stopTime={float(stop_time)!r}",
             f"--resultFile={result_file}", str(ssp_path)], cli_env())


def read_cli_result(path: str | Path, system: str, recorded
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Times and the ``recorded`` ports' columns (``delaycomp.system.Port``) of a
    command-line result CSV of the SSD system ``system``. OMSimulator writes each
    communication point twice (before and after the input update): the last row of each
    time is kept, the state our master records."""
    import csv

    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh, skipinitialspace=True))
    header = rows[0]
    cols = [header.index(f"{system}.{system}.{p.instance}.{p.variable}") for p in recorded]
    table = np.array(rows[1:], dtype=float)
    keep = np.append(table[1:, 0] != table[:-1, 0], True)
    table = table[keep]
    return table[:, 0], table[:, cols]


# -- the cross-check -------------------------------------------------------------------------

def missing() -> list[str]:
    """``[]`` when OMSimulator is found, else why not (for ``delaycomp.verify.check``)."""
    try:
        locate()
    except NotInstalled as exc:
        return [str(exc) if os.environ.get(ENV) else "OMSimulator"]
    return []


def provider(cases):
    """The ``omsimulator`` rows of ``delaycomp.verify.check``: each case's plain archive (no
    Jacobi variant: OMSimulator orders the feedthrough chain itself) through the Python
    API, against the case's reference trace, with the tolerances of every master."""
    from delaycomp.formats.ssp import loop_system, pack
    from delaycomp.verify.cases import CheckRow, compare

    for c in cases:
        with tempfile.TemporaryDirectory(prefix="delaycomp-check-") as tmp:
            path = pack(*loop_system(c.loop(), c.case), Path(tmp) / "case.ssp")
            res = run_ssp(path, c.stop_time())
        if not res.success:
            yield CheckRow(c.id, "omsimulator", float("inf"), "-", False, res.message)
            continue
        cmp = compare(c, res.names, res.times, res.data)
        yield CheckRow(c.id, "omsimulator", cmp.max_error, cmp.tolerance, cmp.passed,
                       "plain archive, Python API")
