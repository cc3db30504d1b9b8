"""Run a packed scenario (``.ssp``) in co-simulation masters we did not write.

Two masters, both installed from PyPI (the ``test`` extra):

- **libcosim** (``libcosimpy``, Open Simulation Platform): loads the ``.ssp`` itself, takes
  the base step from ``osp:FixedStepAlgorithm`` and the component parameter sets;
- **Ecos** (``ecospy``): loads the ``.ssp`` itself, takes the step size in code and applies
  the parameter set named in ``init()`` (every set of our systems has the same name).

Both are Jacobi masters. Measured here (``tests/test_thirdparty.py`` keeps the probe): after
stepping every component from ``t_k`` to ``t_{k+1}`` they read *every* output and only then
set the inputs. So an output that depends on an input at the same instant (direct
feedthrough) is read with the input of the previous step: each such connection adds one base
step ``h`` of latency. In our loop that concerns

- the controller at a sampling instant: it would hand the master a control computed from
  ``x(t_i - h - r)`` and then commit one computed from ``x(t_i - r)``: no choice of delays
  makes that exact, so the controller has a parameter ``held_sample = true`` with which it
  reads, at ``t_i``, the measurement held over ``[t_i - h, t_i)``: its output no longer
  depends on the input at the same instant, and the measurement delay is shortened by ``h``
  so that this held value is exactly ``x(t_i - r)``;
- a delay FMU whose delay is 0 (pure feedthrough): it is bypassed (the connection goes
  straight through), since a zero delay cannot be shortened.

The plant and a delay with ``delay >= h`` have no direct feedthrough (their outputs at
``t_k`` depend on inputs before ``t_k``), so those connections add nothing. The resulting
*Jacobi variant* (``jacobi_variant``) has the same total delays ``r`` and ``tau`` and,
in any of the three masters (ours included), the same trajectory as the scenario in ours,
to round-off. It needs ``r >= 2 h``: the shortened measurement delay must keep one base
step, since without a delay FMU in front of it the controller would read the plant's output
directly, and both masters take that output before the plant has left initialization (0
instead of ``x0``; measured). A scenario with ``r < 2 h`` is refused with a message saying
so.

pythonfmu FMUs run inside the host's interpreter (one per process), so every run happens in
a fresh Python process (``run_ssp``): a master that crashes, or FMUs of another build
that share module names, cannot take the caller with them. It costs about 4 s per run
(interpreter, imports, loading the master); repeated runs of one archive in one process
measured 0.4-0.8 s each and gave identical results, but nothing guarantees that across
builds.
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from delaycomp.child import module_argv
from delaycomp.orchestrator.simulate import Result
from delaycomp.system import Loop
from delaycomp.system.jacobi import (  # noqa: F401 - re-exported: the variant is run here
    JACOBI_LATENCY_STEPS,
    CompensationError,
    jacobi_variant,
)

MASTERS = ("libcosim", "ecos")
# -- running -------------------------------------------------------------------------------

def run_ssp(master: str, ssp_path: str | Path, stop_time: float,
            timeout: float = 900.0) -> Result:
    """Run ``ssp_path`` in ``master`` from 0 to ``stop_time``, in a fresh Python process.

    The result has one row per base step (``t_k = k h``, ``k = 0 .. stop_time / h``) and the
    columns the SSD records (``plant.x``, ``controller.u``, ...), as our master's.
    """
    if master not in MASTERS:
        raise ValueError(f"unknown master {master!r}: allowed are {', '.join(MASTERS)}")
    with tempfile.TemporaryDirectory(prefix="delaycomp-3p-") as tmp:
        out = Path(tmp) / "result.npz"
        # the child leaves with os._exit (see the end of this module), so the folders
        # its master unpacks into (Ecos: a 2.2 MB ecos_ssp_* per run) are never removed
        # by their owners: they go into this folder, removed with it
        env = {**os.environ, "TMPDIR": tmp, "TEMP": tmp, "TMP": tmp}
        proc = subprocess.run(
            module_argv("delaycomp.verify.thirdparty", master, str(Path(ssp_path).resolve()),
                        repr(float(stop_time)), str(out)),
            capture_output=True, text=True, timeout=timeout, cwd=tmp, env=env)
        if proc.returncode != 0 or not out.exists():
            lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
            reason = lines[-1] if lines else f"exit status {proc.returncode}"
            return Result([], np.zeros(0), np.zeros((0, 0)), False, f"{master}: {reason}")
        with np.load(out) as z:
            names = json.loads(str(z["names"]))
            return Result(names, z["times"], z["data"], bool(z["success"]),
                          str(z["message"])).checked_finite(master)


def _run_libcosim(ssp_path: Path, spec: Loop, ticks: int) -> tuple[np.ndarray, str]:
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(str(ssp_path))  # base step: osp:FixedStepAlgorithm
    index = {info.name.decode(): info.index for info in ex.slave_infos()}
    refs = {(inst, v.name.decode()): v.reference for inst, i in index.items()
            for v in ex.slave_variables(i)}
    obs = CosimObserver.create_time_series(buffer_size=ticks + 10)
    ex.add_observer(obs)
    for inst, var in ((p.instance, p.variable) for p in spec.recorded):
        obs.start_time_series(index[inst], refs[(inst, var)], CosimVariableType.REAL)
    ok = ex.step(ticks)
    if not ok:
        return np.zeros((0, len(spec.recorded))), "libcosim: a step failed"
    cols = []
    for inst, var in ((p.instance, p.variable) for p in spec.recorded):
        slave, ref = index[inst], refs[(inst, var)]
        # libcosimpy 0.0.6 trims one sample per step number 0 it returns (it takes 0 for
        # "unfilled"): read step 0 on its own, then steps 1 .. ticks.
        t0, s0, v0 = obs.time_series_real_samples(slave, ref, from_step=0, sample_count=2)
        times, steps, values = obs.time_series_real_samples(slave, ref, from_step=1,
                                                            sample_count=ticks)
        steps = [*s0[:1], *steps]
        if steps != list(range(ticks + 1)) or [*t0[:1], *times] != [
                round(k * spec.T / spec.N * 1e9) for k in range(ticks + 1)]:
            return np.zeros((0, len(spec.recorded))), (
                f"libcosim: recorded steps {steps[:2]}..{steps[-2:]}, expected 0..{ticks} "
                "on the base grid")
        cols.append([*v0[:1], *values])
    h_ns = ex.status().current_time / ticks
    if not math.isclose(h_ns * 1e-9, spec.T / spec.N, rel_tol=1e-9):
        return np.zeros((0, len(spec.recorded))), f"libcosim: step {h_ns} ns, not h"
    return np.array(cols, dtype=float).T, ""


def _load_tbb() -> None:
    """Ecos links against oneTBB, which the ``tbb`` wheel puts in ``<prefix>/lib``."""
    for folder in (Path(sys.prefix) / "lib", Path(sys.base_prefix) / "lib"):
        lib = folder / "libtbb.so.12"
        if lib.exists():
            ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
            return


def _run_ecos(ssp_path: Path, spec: Loop, ticks: int, parameter_set: str
              ) -> tuple[np.ndarray, str]:
    if os.name != "nt":
        _load_tbb()
    from ecospy import EcosSimulation

    h = spec.T / spec.N
    ids = [f"{p.instance}::{p.variable}" for p in spec.recorded]
    rows = []
    with EcosSimulation(ssp_path=str(ssp_path), step_size=h) as sim:
        if sim.init(parameter_set=parameter_set) is False:
            return np.zeros((0, len(ids))), "ecos: init failed"
        rows.append([sim.get_real(i) for i in ids])
        for k in range(1, ticks + 1):
            t = sim.step(1)  # step_until can stop one step short: count steps instead
            if not math.isclose(t, k * h, rel_tol=1e-9, abs_tol=1e-12):
                return np.array(rows), f"ecos: time {t!r} after {k} steps, expected {k * h!r}"
            rows.append([sim.get_real(i) for i in ids])
        sim.terminate()
    return np.array(rows, dtype=float), ""


def _worker(master: str, ssp_path: str, stop_time: float, out: str) -> None:
    from delaycomp.formats.ssp import Archive
    from delaycomp.orchestrator.simulate import stop_ticks

    with Archive(ssp_path) as archive:
        assert archive.system is not None  # read by Archive.__enter__
        spec = archive.system.spec
        set_name = archive.system.info.parameter_set
    ticks = stop_ticks(stop_time, spec.T, spec.N)
    if master == "libcosim":
        data, message = _run_libcosim(Path(ssp_path), spec, ticks)
    else:
        data, message = _run_ecos(Path(ssp_path), spec, ticks, set_name)
    k = np.arange(len(data))
    times = (k // spec.N) * spec.T + (k % spec.N) * (spec.T / spec.N)  # as our master
    np.savez(out, names=json.dumps(spec.columns), times=times,
             data=data, success=not message, message=message)


if __name__ == "__main__":  # the per-run process
    _worker(sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4])
    # the result is written: leave without tearing down the master and the pythonfmu
    # runtime it loaded (the teardown of a pythonfmu FMU has corrupted the heap, see
    # delaycomp.verify.crosscheck.simulate_kept)
    sys.stdout.flush()
    os._exit(0)


# -- packing and cross-checks --------------------------------------------------------------

def pack_jacobi(loop: Loop, out: str | Path, fmu_dir: Path | None = None,
                parameter_set: str | None = None) -> Path:
    """``out`` (``.ssp``): the Jacobi variant of ``loop`` with its FMUs."""
    from delaycomp.formats.ssp import DEFAULT_SET, jacobi_info, loop_system, pack

    spec, info = loop_system(loop, parameter_set or DEFAULT_SET)
    return pack(jacobi_variant(spec), jacobi_info(info), out, fmu_dir)


def provider(master: str):
    """A ``delaycomp.verify.check.PROVIDERS`` entry: each case's Jacobi variant in ``master``,
    against the case's reference trace."""

    def run(cases):
        from delaycomp.verify.cases import CheckRow, compare

        for c in cases:
            with tempfile.TemporaryDirectory(prefix="delaycomp-check-") as tmp:
                try:
                    path = pack_jacobi(c.loop(), Path(tmp) / "case.ssp",
                                       parameter_set=c.case)
                except CompensationError as exc:
                    yield CheckRow(c.id, master, float("inf"), "-", False, str(exc))
                    continue
                res = run_ssp(master, path, c.stop_time())
            if not res.success:
                yield CheckRow(c.id, master, float("inf"), "-", False, res.message)
                continue
            cmp = compare(c, res.names, res.times, res.data)
            yield CheckRow(c.id, master, cmp.max_error, cmp.tolerance, cmp.passed,
                           "Jacobi variant")

    return run
