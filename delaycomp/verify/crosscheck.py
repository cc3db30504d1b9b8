"""Each FMU alone, in the FMI cross-check layout.

For a reference case, our master runs the loop while every component is *tapped*: the
inputs it holds over each base step and the outputs it shows right after each step are
recorded. Each instance then becomes one cross-check model::

    <out>/fmus/2.0/cs/linux64/delaycomp/<version>/<Model>/
        <Model>.fmu       the FMU with the scenario's parameters as its start values
        <Model>_in.csv    its inputs, piecewise constant over each base step
        <Model>_ref.csv   its outputs at every base step
        <Model>_ref.opt   StartTime, StopTime, StepSize (the base step h), RelTol
        README.md         what the model is and how the files were made

with ``<Model> = <scenario>_<case>_<instance>`` (``example-3.6_fig3_controller``).
``python -m fmpy.cross_check.validate_vendor_repo <out>`` accepts the tree.

Decisions, from the FMI cross-check rules (``FMI-CROSS-CHECK-RULES.md`` of
modelica/fmi-cross-check) and from fmpy's ``simulate_fmu``:

- An importer sets no parameter: it runs the FMU with its start values and the
  ``_in.csv``. So each model gets its own FMU whose start values are the scenario's. It is
  the cached FMU repackaged, not rebuilt: the parameters go into the bundled
  ``delaycomp_fmu.json`` (``start``, applied by ``delaycomp.fmu.slave.TableSlave`` at
  registration) and into the modelDescription's ``start`` attributes, with the GUID of that
  configuration; a test checks that pythonfmu builds the same modelDescription from it.
- The rules interpolate ``_in.csv`` linearly. The loop holds every input over a base step,
  so where an input changes the file has two rows at the same time (the value before, then
  the value after). fmpy's ``Input`` applies at a communication point the value after such
  a step (``after_event=True``), which is what the FMU got in the loop.
- fmpy (FMI 2 co-simulation) reads the outputs at the end of each step *before* it sets the
  inputs of the next one; at the start time it reads them after setting the first inputs.
  ``_ref.csv`` holds the outputs as such an importer sees them: the tap reads them right
  after ``doStep``. For outputs without direct feedthrough (plant, delays with a delay of at
  least one step) these are the loop's values; for the controller at a sampling instant and
  a zero delay they are the outputs for the input held over the previous step (the loop
  reads them again once it has set the new input, and records those).

Tolerance (``ALONE_TOL``): the FMU alone gets the inputs it got in the loop; only the
communication points differ by round-off (fmpy steps to ``t0 + (n + 1) h``, our master to
``t0 + i T + j h``). Every component of the reference cases is an exact flow or a closed
form, so the difference is round-off: ``|error| <= 1e-9 (1 + |ref|)``. An ODE-solved plant
(a model without ``step``) would differ by its solver tolerance per step instead.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from delaycomp.child import module_argv
from delaycomp.names import CONFIG_NAME
from delaycomp.tmpfiles import write_text
from delaycomp.verify.cases import EXACT_TOL, CheckRow, RefCase
from delaycomp.version import __version__

#: tool folder of the cross-check tree
TOOL = "delaycomp"
#: platform folder (the FMUs carry linux64 and win64 binaries; the tree is generated here)
PLATFORM = "linux64"
#: sampling periods simulated per case (the cross-check files stay well under 1 MB)
PERIODS = 6
#: FMU alone against its ``_ref.csv``: ``|error| <= ALONE_TOL (1 + |ref|)``
ALONE_TOL = EXACT_TOL


def models_dir(out: Path) -> Path:
    """``<out>/fmus/2.0/cs/linux64/delaycomp/<version>``."""
    return Path(out) / "fmus" / "2.0" / "cs" / PLATFORM / TOOL / __version__


def model_name(c: RefCase, instance: str) -> str:
    """The cross-check folder's name of ``instance`` of case ``c``."""
    return f"{c.scenario}_{c.case}_{instance}"


def stop_time(c: RefCase) -> float:
    """``PERIODS`` sampling periods, or the reference's stop time if shorter."""
    return min(c.stop_time(), PERIODS * c.loop().T)


# -- recording the loop ------------------------------------------------------------------

@dataclass
class Trace:
    """What one instance got and showed during the loop."""

    instance: str
    kind: str
    config: dict
    parameters: dict
    input_names: list[str]
    output_names: list[str]
    #: ``t_0 .. t_K``
    times: list[float]
    #: ``inputs[k]``: the inputs held over ``[t_k, t_{k+1})``, k < K
    inputs: list[list[float]]
    #: ``outputs[0]`` after the first inputs are set; ``outputs[k]``, k >= 1, right after
    #: the step into ``t_k``
    outputs: list[list[float]]


class _Tap:
    """A master component that records what passes through another one."""

    def __init__(self, inner):
        self.inner = inner
        self.name = inner.name
        self.input_names = list(inner.input_names)
        self.output_names = list(inner.output_names)
        self.feedthrough_outputs = inner.feedthrough_outputs
        self._current = dict.fromkeys(self.input_names, 0.0)
        self.inputs: list[list[float]] = []
        self.outputs: list[list[float]] = []

    # the master must go through set_inputs/get_outputs (recorded), not the inner
    # component's hot-path reader/writer (which __getattr__ would hand out)
    reader = writer = None

    def __getattr__(self, name):  # last_message, messages, ... of the FMU
        return getattr(self.inner, name)

    def setup(self, start_time, stop_time, parameters):
        self.inner.setup(start_time, stop_time, parameters)

    def initialize(self):
        self.inner.initialize()

    def set_inputs(self, names: Sequence[str], values: Sequence[float]) -> None:
        self.inner.set_inputs(names, values)
        self._current.update(zip(names, (float(v) for v in values)))

    def get_outputs(self, names: Sequence[str]) -> list[float]:
        return self.inner.get_outputs(names)

    def first_outputs(self) -> None:
        self.outputs.append([float(v) for v in self.inner.get_outputs(self.output_names)])

    def do_step(self, t: float, h: float) -> None:
        self.inputs.append([self._current[n] for n in self.input_names])
        self.inner.do_step(t, h)
        self.outputs.append([float(v) for v in self.inner.get_outputs(self.output_names)])

    def terminate(self):
        self.inner.terminate()


def record_case(c: RefCase, fmu_dir: Path | None = None) -> dict[str, Trace]:
    """Run the loop of ``c`` to ``stop_time`` with every instance tapped."""
    from delaycomp.fmu.cache import source_fmu
    from delaycomp.orchestrator.fmu import FmuComponent
    from delaycomp.orchestrator.simulate import make_master

    spec = c.loop()
    stop = stop_time(c)
    ticks = spec.timing.ticks(stop)
    taps = {i.name: _Tap(FmuComponent(i.name, source_fmu(i.source, fmu_dir)))
            for i in spec.instances}
    master, recorder = make_master(spec, components=list(taps.values()))
    try:
        master.setup(stop, spec.parameters())
        master.initialize()
        for tap in taps.values():
            tap.first_outputs()
        master.run_until(ticks)
    finally:
        master.terminate()
    traces = {}
    for inst in spec.instances:
        kind, config = inst.source.build_key()
        tap = taps[inst.name]
        traces[inst.name] = Trace(inst.name, kind, config, dict(inst.parameters),
                                  tap.input_names, tap.output_names, list(recorder.times),
                                  tap.inputs, tap.outputs)
    return traces


# -- the files ---------------------------------------------------------------------------

def _num(v: float) -> str:
    return repr(float(v))


def _header(names: Iterable[str]) -> str:
    return ",".join(f'"{n}"' for n in ["time", *names])


def input_csv(trace: Trace) -> str:
    """Inputs as the rules want them: linear interpolation of the rows gives the held
    input; a change at ``t_k`` is two rows at ``t_k``."""
    lines = [_header(trace.input_names)]
    rows = trace.inputs
    times = trace.times
    lines.append(",".join(_num(v) for v in [times[0], *rows[0]]))
    for k in range(1, len(rows)):
        if rows[k] != rows[k - 1]:
            lines.append(",".join(_num(v) for v in [times[k], *rows[k - 1]]))
            lines.append(",".join(_num(v) for v in [times[k], *rows[k]]))
    lines.append(",".join(_num(v) for v in [times[-1], *rows[-1]]))
    return "\n".join(lines) + "\n"


def ref_csv(trace: Trace) -> str:
    """The FMU's trace as a cross-check ``_ref.csv`` (quoted header, ``repr`` numbers)."""
    lines = [_header(trace.output_names)]
    lines += [",".join(_num(v) for v in [t, *row])
              for t, row in zip(trace.times, trace.outputs)]
    return "\n".join(lines) + "\n"


def ref_opt(trace: Trace) -> str:
    """The cross-check ``_ref.opt`` of the trace: start, stop, step and the tolerance."""
    h = trace.times[1] - trace.times[0]
    return (f"StartTime, {_num(trace.times[0])}\nStopTime, {_num(trace.times[-1])}\n"
            f"StepSize, {_num(h)}\nRelTol, {ALONE_TOL!r}\n")


def readme(c: RefCase, trace: Trace, ident: str) -> str:
    """The cross-check folder's README of the FMU: the case, the FMU, its parameters."""
    params = "\n".join(f"| `{k}` | {v!r} |" for k, v in trace.parameters.items())
    return f"""# {model_name(c, trace.instance)}

The `{trace.instance}` of reference case `{c.id}` (`delaycomp run {c.scenario}
{' '.join('--set ' + s for s in c.sets)}`), alone: FMU `{ident}` (FMI 2.0 co-simulation,
pythonfmu) whose start values are the scenario's parameters:

| parameter | start value |
|---|---|
{params}

`_in.csv` holds the inputs it received in delaycomp's master (held over each base step;
a change is two rows at the same time), `_ref.csv` its outputs read at the end of each
step before the next inputs are set, from t = 0 to the StopTime of `_ref.opt` with the
communication step StepSize. Run it with the `_in.csv` at that communication step; the
outputs must match `_ref.csv` to `1e-9 (1 + |ref|)` (round-off).

Generated by `delaycomp crosscheck --out DIR` (delaycomp {__version__}); the FMU
needs a Python with numpy and scipy on the host (pythonfmu).
"""


def variant_fmu(src: Path, start: dict, dest: Path) -> Path:
    """``src`` with ``start`` as its parameters' start values (see the module docstring),
    each written as it reads back exactly (``delaycomp.fmu.build.start_text``)."""
    from delaycomp.fmu.build import set_start
    from delaycomp.fmu.slave import pinned_guid

    with zipfile.ZipFile(src) as zin:
        xml = zin.read("modelDescription.xml").decode("utf-8")
        config = json.loads(zin.read(f"resources/{CONFIG_NAME}").decode("utf-8"))
        found = re.search(r'modelIdentifier="([^"]+)"', xml)
        if found is None:  # a delaycomp FMU always names it
            raise ValueError(f"{src}: its modelDescription.xml names no modelIdentifier")
        ident = found.group(1)
        config["start"] = dict(start)
        xml = re.sub(r'guid="[^"]*"', f'guid="{pinned_guid(ident, config)}"', xml, count=1)
        for name, value in start.items():
            xml = set_start(xml, name, value)
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.with_name(dest.name + ".part")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
            for info in zin.infolist():
                if info.filename == "modelDescription.xml":
                    data = xml.encode("utf-8")
                elif info.filename == f"resources/{CONFIG_NAME}":
                    data = json.dumps(config, sort_keys=True).encode("utf-8")
                else:
                    data = zin.read(info)
                zout.writestr(info, data)
        tmp.replace(dest)
    return dest


def write_model(c: RefCase, trace: Trace, folder: Path, fmu_src: Path | None) -> Path:
    """Write one model folder; with ``fmu_src`` also its ``.fmu``."""
    name = model_name(c, trace.instance)
    model = folder / name
    model.mkdir(parents=True, exist_ok=True)
    from delaycomp.fmu.build import model_identifier

    ident = model_identifier(trace.kind, trace.config)
    if fmu_src is not None:
        variant_fmu(fmu_src, trace.parameters, model / f"{name}.fmu")
    files = {"_in.csv": input_csv(trace), "_ref.csv": ref_csv(trace), "_ref.opt": ref_opt(trace)}
    for suffix, text in files.items():
        write_text(model / f"{name}{suffix}", text)  # whole, never through a link
    write_text(model / "README.md", readme(c, trace, ident))
    return model


def generate(out: Path, cases: Iterable[RefCase], fmu_dir: Path | None = None,
             with_fmus: bool = True) -> list[Path]:
    """Write the cross-check models of ``cases`` under ``out``; return their folders."""
    from delaycomp.fmu.cache import fmu_path

    folder = models_dir(out)
    made = []
    for c in cases:
        for trace in record_case(c, fmu_dir).values():
            src = fmu_path(trace.kind, trace.config, fmu_dir) if with_fmus else None
            made.append(write_model(c, trace, folder, src))
    return made


# -- running a model alone ----------------------------------------------------------------

@dataclass(frozen=True)
class AloneResult:
    """One FMU run alone against its reference: the model, the largest error, whether it passed,
    and why not."""

    model: str
    max_error: float
    passed: bool
    message: str = ""


def read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """A CSV's header and its rows as an array of floats."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array(rows[1:], dtype=float)


def simulate_kept(fmu_file: Path, **kwargs):
    """``fmpy.simulate_fmu(fmu_file, **kwargs)`` on an FMU instance that is never freed.

    For child processes only (``run_alone_batch``). fmpy frees the FMU's library after
    a run; pythonfmu's runtime does not survive that reliably (measured: intermittent heap
    corruption, "corrupted double-linked list", in about one run in fifty). The child keeps
    the instance and leaves with ``os._exit`` once it has printed its result.
    """
    from fmpy import read_model_description, simulate_fmu
    from fmpy.simulation import instantiate_fmu

    from delaycomp.tmpfiles import mkdtemp
    from delaycomp.unpack import extract

    unzipdir = str(extract(fmu_file, mkdtemp("delaycomp-fmu-")))  # within the limits
    md = read_model_description(unzipdir)
    instance = instantiate_fmu(unzipdir, md, "CoSimulation")
    return simulate_fmu(unzipdir, model_description=md, fmu_instance=instance, **kwargs)


def run_alone(model: Path) -> AloneResult:
    """``fmpy.simulate_fmu`` on ``<Model>.fmu`` with its ``_in.csv`` against ``_ref.csv``
    (in a child process: see ``simulate_kept``)."""
    from fmpy.util import read_csv, read_ref_opt_file

    name = model.name
    opt = read_ref_opt_file(str(model / f"{name}_ref.opt"))
    header, ref = read_table(model / f"{name}_ref.csv")
    res = simulate_kept(model / f"{name}.fmu", start_time=opt["StartTime"],
                        stop_time=opt["StopTime"], output_interval=opt["StepSize"],
                        input=read_csv(str(model / f"{name}_in.csv")), output=header[1:])
    got_t = np.asarray(res["time"], dtype=float)
    if len(got_t) != len(ref) or not np.allclose(got_t, ref[:, 0], rtol=0,
                                                 atol=1e-9 * opt["StepSize"]):
        return AloneResult(name, math.inf, False,
                           f"{len(got_t)} rows to t = {got_t[-1]!r}, reference {len(ref)}")
    got = np.column_stack([np.asarray(res[n], dtype=float) for n in header[1:]])
    err = np.abs(got - ref[:, 1:])
    if not np.all(np.isfinite(err)):
        return AloneResult(name, math.inf, False, "not finite")
    return AloneResult(name, float(err.max()),
                       bool(np.all(err <= ALONE_TOL * (1.0 + np.abs(ref[:, 1:])))))


def run_alone_batch(models: Sequence[Path]) -> list[AloneResult]:
    """``run_alone`` on each model, each in a fresh Python process.

    ``fmpy.simulate_fmu`` frees each FMU's library after the run, and pythonfmu's runtime
    does not survive that within one process: a later pythonfmu FMU in the same process
    failed (``'NoneType' object is not callable``) or the process aborted on a corrupted
    heap (measured, intermittently, with four FMUs run one after another). One process per
    FMU keeps every run clean, at about a second of start-up each.
    """
    results = []
    for model in models:
        proc = subprocess.run(module_argv("delaycomp.verify.crosscheck", str(model)),
                              capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            reason = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            raise RuntimeError(f"running {Path(model).name} alone failed: {reason}")
        results += [AloneResult(**r) for r in json.loads(proc.stdout.strip().splitlines()[-1])]
    return results


def run_alone_cases(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """Each FMU alone (fmpy.simulate_fmu with the ``_in.csv``) against its ``_ref.csv``."""
    tol = f"{ALONE_TOL:g} x (1 + abs(ref))"
    with tempfile.TemporaryDirectory(prefix="delaycomp-xc-") as tmp:
        for c in cases:
            try:
                models = generate(Path(tmp), [c])
                results = run_alone_batch(models)
            except Exception as exc:  # noqa: BLE001 - one failed case is one failed row
                yield CheckRow(c.id, "fmu-alone", math.inf, tol, False,
                               f"{type(exc).__name__}: {exc}")
                continue
            worst = max(results, key=lambda r: r.max_error)
            failed = [r.model for r in results if not r.passed]
            note = (f"failed: {', '.join(failed)}" if failed else "")
            yield CheckRow(c.id, "fmu-alone", worst.max_error, tol, not failed,
                           note or f"{len(results)} FMUs")
            shutil.rmtree(models_dir(Path(tmp)), ignore_errors=True)


def _main(argv: list[str]) -> int:
    """Child process of ``run_alone_batch``: one JSON list of results on stdout."""
    from dataclasses import asdict

    results = [asdict(run_alone(Path(m))) for m in argv]
    print(json.dumps(results), flush=True)
    os._exit(0)  # no interpreter teardown with a pythonfmu FMU loaded (simulate_kept)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
