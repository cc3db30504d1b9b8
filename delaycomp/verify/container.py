"""The whole loop as one FMU: a container FMU made with fmu-manipulation-toolbox.

``delaycomp export-loop SCENARIO --out FILE.fmu`` puts the plant, the two delays and the
controller of a ``Loop`` into one FMI 2.0 co-simulation FMU
(fmu-manipulation-toolbox's FMU container). The container steps its FMUs at the base step
``h = T/N`` inside each of its own communication steps, so an importer runs it with
``output_interval = T`` and gets the loop at the sampling instants.

Timing (measured, see docs/explanation/verification.md). The container does
not set inputs and read outputs at the same instant as our master does: for each FMU in
turn it sets the inputs from the latest outputs it holds, calls ``doStep`` and reads the
outputs (sequential mode; the default parallel mode sets all, steps all, reads all, i.e.
Jacobi). An output is thus read right after ``doStep``, before the next inputs are set. For
the controller that read comes at each sampling instant with the measurement of the
previous step (direct feedthrough), so no order and no delay shift makes the loop exact;
measured on Example 3.6, Figure 3: errors 0.02 to 3.4 in ``x`` at the sampling instants.

What is exact instead:

1. the controller samples the input held over the step that ends at ``t_i``
   (``held_sample = true``): its output has no direct feedthrough any more;
2. the container steps in the order ``meas_delay, input_delay, plant, controller``
   (sequential), so that over the step ``[t_k, t_{k+1})``

   - ``meas_delay`` gets ``x(t_k)`` (the plant's output after its previous step), as in
     our master, and its output after the step is ``x(t_{k+1} - r)`` (``r >= h``: it
     needs no input at ``t_{k+1}``); the controller, stepped after it, holds that over
     ``[t_k, t_{k+1})``: with (1) its sample at ``t_{k+1}`` is the true ``x(t_{k+1} - r)``.
     A network channel there gets each packet at the step our master sends it, so its
     draws (which go by packet number) are the same;
   - ``input_delay`` gets the controller's output at ``t_k`` (read after its previous
     step) and ``plant`` gets the delay's output just computed: one step of delay more
     than in our master, so the input delay is ``tau + h`` (a channel's every packet,
     ``delaycomp.system.jacobi.shifted_delay``).

   The added step is filled by the delay's initial history, which is the loop's own
   (``u0``). Every FMU then gets exactly what it gets in our master; the
   container is tested against the reference traces at the sampling instants with the
   tolerances of ``delaycomp.verify.check``, and with a channel against ``run`` bit for
   bit.

The measurement delay must be at least one base step (``r >= h``): with ``r = 0`` the
controller needs ``x(t_i)`` before ``t_i`` is reached, which only direct feedthrough gives.

FMI 3.0 (``export-loop --fmi 3``, ``export_loop(..., fmi=3)``): the container's own
interface is FMI 3.0 (the toolbox's ``fmi_version=3``) and it holds delaycomp's FMI 3.0
native FMUs, each built with its instance's values as start values
(``delaycomp.formats.loopbuild.native_with_starts``): the container sets scalar start
values only (an array's elements are not its ports), so it sets the scalars the order needs
(``delay``, ``held_sample``) and the arrays come with the FMUs. A user's FMU file (another
tool's FMI 2.0 plant) goes in as it is, its start values set element by element. The loop
inside is the FMI 2.0 container's, bit for bit (``tests/test_container.py``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import re
import shutil
import tempfile
from collections.abc import Collection, Iterable
from pathlib import Path
from typing import cast

from delaycomp.child import module_argv
from delaycomp.errors import DelaycompError, ParameterError
from delaycomp.names import array_element
from delaycomp.system import Loop, Role
from delaycomp.system.jacobi import shifted_delay
from delaycomp.verify.cases import CheckRow, RefCase, compare

#: inner order of the container, by role (see the module docstring)
ORDER: tuple[Role, ...] = ("meas_delay", "input_delay", "plant", "controller")
#: base steps added to each delay (by role) to absorb the container's order
ADDED_STEPS = {"input_delay": 1}


class ContainerError(DelaycompError, RuntimeError):
    """fmu-manipulation-toolbox is missing or refused the description."""


def _toolbox():
    try:
        from fmu_manipulation_toolbox.assembly import Assembly
    except ImportError:
        raise ContainerError(
            "export-loop needs fmu-manipulation-toolbox >= 2.0: pip install "
            "'delaycomp[container]'") from None
    return Assembly


def exposed(spec: Loop) -> list:
    """The recorded ports the container exposes: all but the delays' outputs (a plant
    FMU's input columns, ``Loop.labels``), which the container's order shifts by the
    step it adds to the input delay (``ADDED_STEPS``): there they are not what the plant
    receives at that instant."""
    delays = {i.name for i in spec.instances if i.role in ADDED_STEPS}
    return [p for p in spec.recorded if p.instance not in delays]


def output_names(spec: Loop) -> dict[str, str]:
    """Container output name -> the loop's column (``plant.x``), in the recorded order of
    the ports it exposes (``exposed``): the variable's own name, or
    ``instance_variable`` where two of them share a variable name."""
    ports = exposed(spec)
    names = [p.variable for p in ports]
    unique = len(set(names)) == len(names)
    return {(p.variable if unique else f"{p.instance}_{p.variable}"): spec.column(p)
            for p in ports}


def _ordered(spec: Loop) -> list:
    """The loop's instances in the container's order (by role); all four roles needed."""
    members = [spec.by_role(role) for role in ORDER]
    if None in members or len(spec.instances) != len(ORDER):
        raise ParameterError(f"a loop container needs exactly the roles {', '.join(ORDER)}")
    return cast(list, members)


def _checked(spec: Loop) -> list:
    """The loop's instances in the container's order, once the loop is one the
    container runs exactly (the four roles, ``r >= h``); else ``ParameterError``."""
    members = _ordered(spec)
    h = spec.h
    meas = members[ORDER.index("meas_delay")].parameters["delay"]
    if meas < h * (1 - 1e-9):
        raise ParameterError(
            f"parameter r = {meas!r} is not allowed for export-loop: the measurement delay "
            f"must be at least one base step h = T/N = {h!r} (the container reads outputs "
            "before it sets inputs, so r = 0 would need direct feedthrough)")
    return members


def _text(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (str, int)):
        return str(value)
    return repr(float(value))


def description(spec: Loop, fmu_files: dict[str, str], name: str,
                arrays_in_fmu: Collection[str] = ()) -> dict:
    """The container's JSON description (fmu-manipulation-toolbox's format). The
    instances named in ``arrays_in_fmu`` are FMI 3.0 FMUs that carry their arrays as
    start values: the container sets only their scalars."""
    members = _checked(spec)
    h = spec.h
    start = []
    for inst in members:
        params = dict(inst.parameters)
        if inst.role in ADDED_STEPS:
            params.update(shifted_delay(params, ADDED_STEPS[inst.role] * h))
        if inst.role == "controller":
            params["held_sample"] = True
        if inst.name in arrays_in_fmu:
            params = {k: v for k, v in params.items() if array_element(k) is None}
        start += [[f"{inst.name}.fmu", key, _text(value)] for key, value in params.items()]
    links = [[f"{c.src.instance}.fmu", c.src.variable, f"{c.dst.instance}.fmu",
              c.dst.variable] for c in spec.connections]
    outputs = [[f"{port.instance}.fmu", port.variable, out]
               for port, out in zip(exposed(spec), output_names(spec))]
    return {
        "name": name, "step_size": h, "sequential": True, "mt": False,
        "auto_link": False, "auto_input": False, "auto_output": False,
        "auto_parameter": False, "auto_local": False,
        "fmu": [f"{inst.name}.fmu" for inst in members],
        "path": {f"{inst.name}.fmu": fmu_files[inst.name] for inst in members},
        "link": links, "output": outputs, "start": start,
    }


def _identifier(path: Path) -> str:
    ident = re.sub(r"\W", "_", path.stem)
    return ident if ident and not ident[0].isdigit() else f"loop_{ident}"


class _UndrivenInputs(logging.Filter):
    """Drops fmu-manipulation-toolbox's error ``Input 'Port plant.fmu/load.tau' is not
    connected`` for the inputs of a user's FMU that the loop leaves at their start values
    on purpose (``delaycomp.system.plantfmu.undriven_inputs``: the command says so
    once, as a note); any other such error passes."""

    def __init__(self, spec: Loop):
        super().__init__()
        from delaycomp.system.plantfmu import undriven_inputs

        self.messages = {f"Input 'Port {name}.fmu/{v.name}' is not connected"
                         for name, free in undriven_inputs(spec).items() for v in free}

    def filter(self, record: logging.LogRecord) -> bool:
        return record.getMessage() not in self.messages


def export_loop(spec: Loop, out: Path, fmu_dir: Path | None = None,
                fmus: dict[str, Path] | None = None, fmi: int = 2) -> Path:
    """Write the loop ``spec`` as one container FMU to ``out``; return ``out``.

    Parameters
    ----------
    spec : Loop
        The loop: the four roles, ``r >= h``.
    out : Path
        The ``.fmu`` file to write (replaced whole, never through a link).
    fmu_dir : Path, optional
        Folder of built Python FMUs (default: the per-version cache).
    fmus : dict, optional
        The FMU file of some instances (e.g. the native ones of
        ``delaycomp.fmu.twins.native_fmus``); the others come from their sources. Not
        with ``fmi=3``, which builds its own.
    fmi : {2, 3}
        The FMI version of the container's interface and of delaycomp's FMUs inside it:
        3 holds the FMI 3.0 native FMUs, built with the loop's values as start values
        (a user's FMU file goes in as it is).

    Raises
    ------
    ParameterError
        ``fmi`` other than 2 or 3, ``fmus`` with ``fmi=3``, ``r < h``, a loop without the
        four roles.
    ContainerError
        fmu-manipulation-toolbox is missing or refused the description.
    """
    from delaycomp.fmu.cache import source_fmu
    from delaycomp.tmpfiles import replacing_path
    from delaycomp.unpack import Budget, measure

    if isinstance(fmi, bool) or fmi not in (2, 3):
        raise ParameterError(f"fmi = {fmi!r} is not allowed: must be 2 or 3")
    if fmi == 3 and fmus:
        raise ParameterError("fmus is not allowed with fmi = 3: the container holds "
                             "delaycomp's FMI 3.0 FMUs built with the loop's values as start "
                             "values (it sets no array)")
    Assembly = _toolbox()
    out = Path(out)
    ident = _identifier(out)
    with tempfile.TemporaryDirectory(prefix="delaycomp-loop-") as tmp:
        work = Path(tmp)
        if fmi == 3:
            from delaycomp.formats.loopbuild import native_with_starts

            _checked(spec)  # the loop's own refusals before any build
            # the arrays the container cannot set (a channel's trace) start shifted too
            shifted = spec.with_instances(
                i.with_parameters(**shifted_delay(i.parameters, ADDED_STEPS[i.role] * spec.h))
                if i.role in ADDED_STEPS else i for i in spec.instances)
            fmus = native_with_starts(shifted, work / "fmi3", fmi=3)
        arrays_in_fmu = set(fmus or ()) if fmi == 3 else set()
        files = {}
        for inst in _ordered(spec):
            src = Path((fmus or {}).get(inst.name) or source_fmu(inst.source, fmu_dir))
            # the container's tool unpacks it, with no limit of its own: ours first
            measure(src, Budget(src))
            name = src.name
            if fmi == 3 and inst.name in arrays_in_fmu:  # its own starts: never a file of
                # the same name that another instance brings (a user's plant FMU)
                name = f"{inst.name}_{src.name}"
            if not (work / name).exists():
                shutil.copy2(src, work / name)
            files[inst.name] = name
        desc = description(spec, files, f"{ident}.fmu", arrays_in_fmu)
        (work / "loop.json").write_text(json.dumps(desc, indent=1), encoding="utf-8")
        log = logging.getLogger("fmu_manipulation_toolbox")
        level, propagate = log.level, log.propagate
        log.setLevel(logging.ERROR)  # its notes ("loop of links ...") are expected here
        log.propagate = False
        undriven = _UndrivenInputs(spec)
        log.addFilter(undriven)
        try:
            Assembly("loop.json", fmu_directory=work).make_fmu(fmi_version=fmi)
        except Exception as exc:
            raise ContainerError(f"fmu-manipulation-toolbox: {exc}") from exc
        finally:
            log.removeFilter(undriven)
            log.setLevel(level)
            log.propagate = propagate
        built = work / f"{ident}.fmu"
        if not built.exists():
            raise ContainerError("fmu-manipulation-toolbox wrote no container")
        out.parent.mkdir(parents=True, exist_ok=True)
        with replacing_path(out) as part:  # whole, never through a link
            shutil.copyfile(built, part)
    return out


def simulate_loop(path: Path, spec: Loop, stop_time: float):
    """``fmpy.simulate_fmu`` on the container at ``output_interval = T``: the times and
    the columns ``plant.x ...`` at the sampling instants (those it exposes: not a plant
    FMU's input columns, ``exposed``). A plant FMU file's
    ``tolerance`` goes to the container's ``fmi2SetupExperiment``, which hands it on to
    the FMUs inside (delaycomp's own ignore it)."""
    import numpy as np

    from delaycomp.orchestrator.simulate import Result
    from delaycomp.system import FmuFile
    from delaycomp.verify.crosscheck import simulate_kept

    names = output_names(spec)
    plant = spec.by_role("plant")
    tol = (plant.source.tolerance if plant is not None and isinstance(plant.source, FmuFile)
           else None)
    res = simulate_kept(path, stop_time=stop_time, output_interval=spec.T,
                        output=list(names), relative_tolerance=tol)
    data = np.column_stack([np.asarray(res[n], dtype=float) for n in names])
    times = np.asarray(res["time"], dtype=float)
    # fmpy runs on through a plant's breakdown: held to our master's rule
    checked = Result(list(names.values()), times, data).checked_finite("fmpy")
    if not checked.success:
        raise ContainerError(checked.message)
    return list(names.values()), times, data


def run_container_cases(cases: Iterable[RefCase]) -> Iterable[CheckRow]:
    """The container of each case against its reference at the sampling instants."""
    with tempfile.TemporaryDirectory(prefix="delaycomp-container-") as tmp:
        for c in cases:
            try:
                spec = c.loop()
                path = export_loop(spec, Path(tmp) / "loop.fmu")
                names, times, data = _simulate_in_child(path, c)
                cmp = compare(c, names, times, data, stride=1, ref_stride=spec.N)
            except Exception as exc:  # noqa: BLE001 - one failed case is one failed row
                yield CheckRow(c.id, "container", math.inf, "-", False,
                               f"{type(exc).__name__}: {exc}")
                continue
            yield CheckRow(c.id, "container", cmp.max_error, cmp.tolerance, cmp.passed,
                           "at t0 + iT")


def _simulate_in_child(path: Path, c: RefCase):
    """``simulate_loop`` in a fresh process (see
    ``delaycomp.verify.crosscheck.run_alone_batch``)."""
    import subprocess

    import numpy as np

    proc = subprocess.run(module_argv("delaycomp.verify.container", str(path),
                                      json.dumps(dataclasses.asdict(c))),
                          capture_output=True, text=True, timeout=1200)
    if proc.returncode != 0:
        reason = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise ContainerError(f"simulating the container failed: {reason}")
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    return got["names"], np.array(got["times"]), np.array(got["data"])


def _main(argv: list[str]) -> int:
    path = Path(argv[0])
    fields = json.loads(argv[1])
    c = RefCase(**{**fields, "sets": tuple(fields["sets"])})
    spec = c.loop()
    names, times, data = simulate_loop(path, spec, c.stop_time())
    print(json.dumps({"names": names, "times": times.tolist(), "data": data.tolist()}),
          flush=True)
    os._exit(0)  # no interpreter teardown with a pythonfmu FMU loaded (simulate_kept)


if __name__ == "__main__":
    import sys

    sys.exit(_main(sys.argv[1:]))
