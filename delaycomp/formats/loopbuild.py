"""The FMUs of one loop, ready to instantiate, and its wiring sheet.

``delaycomp build LOOP.toml`` (and ``delaycomp.api.build``) write, for a loop file or a
scenario, one FMU per instance named after the loop (``myloop_plant.fmu``,
``myloop_meas_delay.fmu``, ``myloop_controller.fmu``, ``myloop_input_delay.fmu``) whose
start values are the loop's parameter values (``A``, ``B``, ``K``, ``T``, ``r``, ``tau``,
the histories, ``mode``, a model's parameters): a host that sets no parameter runs the
loop. Beside them ``myloop_wiring.txt``, the wiring sheet: each FMU's inputs and outputs,
what connects to what, the sampling period and the base step a host must use, the order
within a step, and the delays a host must provide itself when it takes only the
controller.

The FMUs are the native C twins wherever the loop has them here (LTI loops, model files
that translate, a C compiler), else the Python FMUs with a note; ``fmus="native"`` or
``"python"`` chooses. An instance whose FMU is a user's file (a plant FMU exported by
another tool) is not rebuilt: the sheet names the file and the loop's values for it.

Every start value is written as it reads back (``delaycomp.fmu.build.start_text``) and
checked after the build against the loop: the modelDescription's start of each parameter
equals the loop's value exactly.

Examples
--------
>>> file_stem("my loop/v2")
'my_loop_v2'
>>> roles_of(["delays", "controller"])
('meas_delay', 'controller', 'input_delay')
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from delaycomp.errors import ParameterError
from delaycomp.names import FMU_KINDS, LOOP_GROUPS, array_element, flat_index
from delaycomp.system.loop import ROLES, FmuFile, Instance, Loop, ModelFmu, Role
from delaycomp.tmpfiles import write_text
from delaycomp.version import __version__

#: what the roles are, for the sheet
ROLE_TEXT = {"plant": "the plant", "meas_delay": "the measurement delay (r)",
             "controller": "the predictor-controller", "input_delay": "the input delay (tau)"}


@dataclass(frozen=True)
class LoopBuild:
    """What ``build_loop`` wrote."""

    #: the loop's name as the files carry it
    name: str
    #: role -> the FMU written for it
    fmus: dict[str, Path]
    #: the wiring sheet
    wiring: Path
    #: native C FMUs (``False``: the Python FMUs)
    native: bool
    #: role -> a user's FMU file that the loop names (used as it is, not rebuilt)
    given: dict[str, Path] = field(default_factory=dict)
    #: what a user should know (a fallback to the Python FMUs, a file not rebuilt)
    notes: tuple[str, ...] = ()

    @property
    def paths(self) -> list[Path]:
        """The files written: the FMUs in signal order, then the wiring sheet."""
        return [*self.fmus.values(), self.wiring]


def file_stem(name: str) -> str:
    """``name`` as the start of a file name: letters, digits, ``.``, ``-`` and ``_``;
    anything else (a separator, a space) becomes ``_``, so a file never lands outside
    the folder given."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", str(name)).strip("._") or "loop"
    return stem


def roles_of(only: Iterable[str] | None) -> tuple[Role, ...]:
    """The roles ``only`` names (``delaycomp.names.LOOP_GROUPS``), in signal order;
    ``None``: every role."""
    if only is None:
        return ROLES
    chosen: set[str] = set()
    for group in only:
        if group not in LOOP_GROUPS:
            raise ParameterError(f"--only {group!r} is not allowed: allowed are "
                                 f"{', '.join(LOOP_GROUPS)}")
        chosen.update(LOOP_GROUPS[group])
    if not chosen:
        raise ParameterError("--only names nothing: allowed are " + ", ".join(LOOP_GROUPS))
    return tuple(r for r in ROLES if r in chosen)


def build_loop(loop: Loop, out_dir: str | Path, *, only: Iterable[str] | None = None,
               fmus: str = "auto", info=None, fmi: int = 2,
               clocked: bool = False) -> LoopBuild:
    """Build the FMUs of ``loop`` into ``out_dir`` with the loop's values as their start
    values, and write its wiring sheet.

    Parameters
    ----------
    loop : Loop
        The loop (``delaycomp.api.load`` of a loop file, a scenario's loop, ...).
    out_dir : path
        Output folder (created). Files are named ``<loop>_<role>.fmu`` and
        ``<loop>_wiring.txt``; existing files of those names are replaced.
    only : iterable of str, optional
        ``plant``, ``controller``, ``delays``: build only these (default: all).
    fmus : str
        ``auto`` (native where the loop has native FMUs here, else Python with a note),
        ``native`` (an error where it cannot) or ``python``.
    info : callable, optional
        ``info(text)`` receives each note as it arises.
    fmi : int
        2, or 3 for FMI 3.0 FMUs (native only: ``fmus`` ``auto`` is ``native``).
    clocked : bool
        With ``fmi=3``: the LTI controller's clocked variant.

    Returns
    -------
    LoopBuild
    """
    from delaycomp.fmu.build import publish
    from delaycomp.tmpfiles import temp_dir

    roles, name, out_dir = _build_args(loop, out_dir, only, fmus)
    notes: list[str] = []

    def note(text: str) -> None:
        notes.append(text)
        if info is not None:
            info(text)

    given, todo = _chosen(loop, roles, note)
    out_dir.mkdir(parents=True, exist_ok=True)
    with temp_dir("delaycomp-loopbuild-") as tmp:
        staged, native = _stage_fmus(loop, todo, name, "native" if fmi == 3 else fmus,
                                     Path(tmp), note, fmi, clocked)
        for inst in todo:
            check_starts(staged[inst.role], inst.parameters, f"{name}_{inst.role}.fmu")
        written: dict[str, Path] = {}
        for role in roles:
            if role in staged:
                written[role] = out_dir / staged[role].name
                publish(staged[role], written[role])
    files = {**written, **given}
    wiring = out_dir / f"{name}_wiring.txt"
    others: dict[str, Path | None] = {i.role: None for i in loop.instances
                                      if i.role not in files}
    write_text(wiring, wiring_sheet(loop, {**others, **files}, roles, native, name, fmi))
    return LoopBuild(name, written, wiring, native, given, tuple(notes))


def _build_args(loop: Loop, out_dir: str | Path, only: Iterable[str] | None,
                fmus: str) -> tuple[tuple[Role, ...], str, Path]:
    """The arguments of ``build_loop`` checked: the roles, the file stem, the folder."""
    if fmus not in FMU_KINDS:
        raise ParameterError(f"fmus = {fmus!r} is not allowed: must be one of "
                             f"{', '.join(FMU_KINDS)}")
    roles = roles_of(only)
    name = file_stem(loop.name)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ParameterError(f"--out {out_dir} is not allowed: it is a file (a folder is "
                             "needed)")
    return roles, name, out_dir


def _chosen(loop: Loop, roles: tuple[Role, ...], note: Callable[[str], None]
            ) -> tuple[dict[str, Path], list[Instance]]:
    """The user's FMU files among the instances of ``roles`` (each noted), and the
    instances to build."""
    chosen = [inst for r in roles if (inst := loop.by_role(r)) is not None]
    if not chosen:
        raise ParameterError(f"loop {loop.name} has no {' or '.join(roles)} to build")
    given: dict[str, Path] = {i.role: Path(i.source.path) for i in chosen
                              if isinstance(i.source, FmuFile)}
    for role, path in given.items():
        note(f"note: the {role} is the loop's own FMU file {path} (used as it is, not "
             "rebuilt: set its parameters as the wiring sheet says)")
    return given, [i for i in chosen if not isinstance(i.source, FmuFile)]


def _stage_fmus(loop: Loop, todo: list[Instance], name: str, fmus: str, tmp: Path,
                note: Callable[[str], None], fmi: int = 2, clocked: bool = False
                ) -> tuple[dict[str, Path], bool]:
    """Build the FMUs of ``todo`` under ``tmp``: native ones unless ``fmus`` says python
    (``auto`` falls back to Python with a note); role -> FMU and whether they are
    native."""
    from delaycomp.fmu.native import NativeBuildError
    from delaycomp.maths.model import ModelError

    native = fmus != "python" and bool(todo)
    staged: dict[str, Path] = {}
    if native:
        try:
            staged = _build_all(todo, name, True, tmp / "native", fmi, clocked)
        except (NativeBuildError, ModelError, ValueError) as exc:
            why = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
            if fmus == "native":
                raise NativeBuildError(f"native FMUs of loop {loop.name}: {why}") from None
            note(f"note: building the Python FMUs (no native ones here: {why}); "
                 "--python says so and skips the attempt")
            native = False
    if not native and todo:
        staged = _build_all(todo, name, False, tmp / "python")
    if native:
        from delaycomp.fmu.native import pop_notes

        for text in pop_notes():  # platforms left out for want of a cross compiler
            note(text)
    return staged, native


def _build_all(todo: list[Instance], name: str, native: bool,
               stage: Path, fmi: int = 2, clocked: bool = False) -> dict[str, Path]:
    """Build each instance of ``todo`` (native or Python) into ``stage``, with its
    parameters as start values; role -> FMU."""
    from delaycomp.fmu.build import build_fmu
    from delaycomp.fmu.native import build_native_fmu

    built: dict[str, Path] = {}
    for inst in todo:
        source = inst.source
        assert not isinstance(source, FmuFile)  # todo holds the instances to build
        kind, config = source.build_key()
        config = {**config, "start": dict(inst.parameters),
                  **({"clocked": True} if clocked and inst.role == "controller" else {})}
        file_name = f"{name}_{inst.role}.fmu"
        if native:
            built[inst.role] = build_native_fmu(kind, stage, config, file_name, fmi=fmi)
        else:
            built[inst.role] = build_fmu(kind, stage, config, file_name)
    return built


def native_with_starts(loop: Loop, stage: Path, fmi: int = 2,
                       clocked: bool = False) -> dict[str, Path]:
    """The native FMU of each instance of ``loop`` but a user's FMU file, built into
    ``stage`` with the instance's parameters as start values (FMI version ``fmi``;
    ``clocked``: the controller's clocked variant); instance name -> path. What ``delaycomp
    ssp --fmi 3`` packs: an importer that cannot apply an array element of the archive's
    parameter sets (SSP 1.0 knows no arrays) still runs the loop."""
    todo = [i for i in loop.instances if not isinstance(i.source, FmuFile)]
    by_role = _build_all(todo, file_stem(loop.name), True, Path(stage), fmi, clocked)
    return {i.name: by_role[i.role] for i in todo}


def check_starts(fmu: Path, parameters: Mapping, label: str) -> None:
    """Every parameter of the loop is a variable of ``fmu`` whose start value reads back
    as the loop's value, exactly (a String as text, an Integer and a Boolean as such)."""
    from fmpy import read_model_description

    variables = {v.name: v for v in read_model_description(str(fmu)).modelVariables}
    for key, value in parameters.items():
        var = variables.get(key)
        start = var.start if var is not None else None
        element = array_element(key)
        array = variables.get(element[0]) if element else None
        if (var is None and element is not None and array is not None and array.dimensions
                and array.start):
            # FMI 3.0: an element of an array, its start the array's (row-major)
            flat = flat_index(element[1], array.shape)
            starts = array.start.split()
            var, start = array, starts[flat] if flat is not None else None
        if var is None or start is None:
            raise RuntimeError(f"{label}: no parameter {key!r} with a start value")
        if var.type in ("Real", "Float64"):
            same = float(start) == float(value)
        elif var.type in ("Integer", "Int32"):
            same = int(start) == int(value)
        elif var.type == "Boolean":
            same = (str(start).lower() in ("true", "1")) == bool(value)
        else:
            same = str(start) == str(value)
        if not same:
            raise RuntimeError(f"{label}: the start value of {key} is {start!r}, the loop's "
                               f"{value!r}")


# -- the wiring sheet ------------------------------------------------------------------------

def _ports(fmu: Path | None) -> tuple[list[str], list[str], set[str]]:
    """Inputs, outputs and the outputs with direct feedthrough (ModelStructure) of ``fmu``."""
    if fmu is None:
        return [], [], set()
    from fmpy import read_model_description

    md = read_model_description(str(fmu))
    ins = [v.name for v in md.modelVariables if v.causality == "input"]
    outs = [v.name for v in md.modelVariables if v.causality == "output"]
    feed = {u.variable.name for u in md.outputs if u.dependencies}
    return ins, outs, feed


def _num(x) -> str:
    """A number as it reads back (``repr``), ``1`` for ``1.0``."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def _vector(parameters: Mapping, base: str) -> list:
    out, i = [], 1
    while f"{base}[{i}]" in parameters:
        out.append(parameters[f"{base}[{i}]"])
        i += 1
    return out


def wiring_sheet(loop: Loop, files: Mapping[str, Path | None], built: Iterable[str],
                 native: bool, name: str, fmi: int = 2) -> str:
    """The wiring sheet of ``loop`` (text): ``files`` maps each role to its FMU file
    (``None``: not built this time); ``built`` are the roles asked for; ``fmi`` the FMI
    version they were built for."""
    from delaycomp.orchestrator.master import feedthrough_order

    built = list(built)
    by_role = {i.role: i for i in loop.instances}
    ports = {r: _ports(files.get(r)) for r in by_role}
    ctrl = by_role.get("controller")
    cp = dict(ctrl.parameters) if ctrl is not None else {}
    L = _sheet_timing(loop, by_role, cp, native, fmi)
    L += ["", "FMUs"]
    L += _sheet_fmus(by_role, ports, files, built, name)
    L += ["", "Connections (output -> input)"]
    L += [f"  {c}" for c in loop.connections]
    have = {r for r, p in files.items() if p is not None}
    feed = {inst.name for r, inst in by_role.items() if ports[r][2]}
    heads = [inst.name for r, inst in by_role.items() if r in have and not ports[r][2]]
    order = feedthrough_order(feed, ((c.src.instance, c.dst.instance)
                                     for c in loop.connections))
    if len(have) == len(by_role):
        L += ["", "Order within each base step (Gauss-Seidel along the signal chain; an "
              "output with direct",
              "feedthrough depends on an input at the same instant):",
              f"  1. read the outputs of {', '.join(heads) or '-'} (no direct feedthrough)",
              f"  2. for {', '.join(order) or '-'}, in this order: set the inputs, read the "
              "outputs",
              f"  3. set the inputs of {', '.join(heads) or '-'}; step every FMU from t_k to "
              "t_k + h",
              "  A host that steps every FMU first and exchanges after (Jacobi: libcosim, Ecos)",
              "  delays each connection by h: `delaycomp ssp --jacobi` packs the variant that "
              "allows for it."]
    L += _controller_alone(loop, by_role, ports, cp)
    return "\n".join(L) + "\n"


def _sheet_timing(loop: Loop, by_role, cp, native: bool, fmi: int = 2) -> list[str]:
    """The sheet's title, what the FMUs are, and its timing section."""
    T, h = loop.T, loop.h
    kind = ("native C: no Python in the host" if native else
            "Python: the host needs Python, see the FMUs' README")
    L = [f"Wiring sheet of loop {loop.name} (delaycomp {__version__})", ""]
    if loop.title:
        L += [loop.title, ""]
    L += [f"FMI {fmi}.0 co-simulation FMUs ({kind}). Their start values are the",
          "loop's: a host that sets no parameter runs this loop.", "",
          "Timing",
          f"  sampling period       T = {_num(T)} s: the controller samples at t0 + i T",
          f"  base step             h = T/N = {_num(h)} s (N = {loop.N}): step every FMU "
          "with communication",
          "                        step h, t_k = t0 + k h (the controller refuses another "
          "step)"]
    if "r" in cp and "tau" in cp:
        L.append(f"  assumed delays        r = {_num(cp['r'])} s (measurement), tau = "
                 f"{_num(cp['tau'])} s (input): the controller")
        L.append("                        predicts over them")
    delays = [f"{by_role[r].name} {_num(by_role[r].parameters['delay'])} s"
              for r in ("meas_delay", "input_delay")
              if r in by_role and "delay" in by_role[r].parameters]
    if delays:
        L.append(f"  delay FMUs            {', '.join(delays)}")
    return L


def _sheet_fmus(by_role, ports, files: Mapping[str, Path | None], built: list[str],
                name: str) -> list[str]:
    """One line per role: its FMU file, inputs and outputs (or that it was not built)."""
    L = []
    width = max(len(str(Path(p).name)) for p in files.values() if p is not None)
    for role in by_role:
        path = files.get(role)
        ins, outs, _ = ports[role]
        if path is None:
            L.append(f"  {'(not built)':<{width}}  {role:<12} {ROLE_TEXT[role]}")
            continue
        given = role not in built or not Path(path).name.startswith(f"{name}_")
        where = str(path) if given else Path(path).name
        tag = "  (the loop's own FMU file, used as it is)" if given else ""
        L.append(f"  {where:<{width}}  {role:<12} inputs {', '.join(ins) or '-'}; "
                 f"outputs {', '.join(outs) or '-'}{tag}")
    return L


def _zoh_unpadded(ctrl, cp) -> bool:
    """Does the controller hold its output over each period with tau = l T (Theorem 3.2
    without padding)? The LTI controller always; a model's under ``zoh`` without ``pad``."""
    if isinstance(ctrl.source, ModelFmu):
        from delaycomp.maths.model import load_model

        zoh = cp.get("mode", load_model(ctrl.source.model).control) == "zoh"
        return zoh and not cp.get("pad", False)
    return True


def _controller_alone(loop: Loop, by_role, ports, cp) -> list[str]:
    """What a host must provide when it takes only the controller."""
    ctrl, plant = by_role.get("controller"), by_role.get("plant")
    if ctrl is None:
        return []
    links = {(c.dst.instance, c.dst.variable): c.src for c in loop.connections}
    md, idl = by_role.get("meas_delay"), by_role.get("input_delay")
    ins, outs, _ = ports["controller"]
    measured = []
    for var in ins:
        src = links.get((ctrl.name, var))
        if src is not None and md is not None and src.instance == md.name:
            up = links.get((md.name, "u" + src.variable[1:]))
            if up is not None:
                measured.append(f"  {ctrl.name}.{var} <- {up}(t - r)")
                continue
        measured.append(f"  {ctrl.name}.{var} <- {src if src is not None else '?'}")
    applied = []
    for var in outs:
        dst = next((c.dst for c in loop.connections
                    if c.src.instance == ctrl.name and c.src.variable == var), None)
        if dst is not None and idl is not None and dst.instance == idl.name:
            down = next((c.dst for c in loop.connections
                         if c.src.instance == idl.name
                         and c.src.variable == "y" + dst.variable[1:]), None)
            if down is not None:
                applied.append(f"  {down}(t) <- {ctrl.name}.{var}(t - tau)")
                continue
        applied.append(f"  {dst if dst is not None else '?'} <- {ctrl.name}.{var}")
    r, tau = cp.get("r"), cp.get("tau")
    x0 = _vector(md.parameters, "u0") if md is not None else []
    u0 = _vector(cp, "u0")
    L = ["", "Taking only the controller",
         "  It predicts over the delays of its loop: its inputs are the plant's state "
         f"measured r = {_num(r) if r is not None else '?'} s",
         f"  ago, its outputs reach the plant tau = {_num(tau) if tau is not None else '?'} s "
         "later:"]
    L += ["  " + line for line in measured + applied]
    L += ["  Your host provides these two delays itself (a transport delay block, the "
          "network) or",
          "  uses the delay FMUs. If its real delays differ, set the controller's r and tau "
          "to them",
          "  (whole numbers of base steps h" + ("; tau a multiple of T)." if _zoh_unpadded(
              ctrl, cp) else ")."),
          "  Before the delays fill, the controller takes the measurement to be the initial "
          "state"]
    L.append("  " + (f"x0 = {', '.join(_num(v) for v in x0)} " if x0 else "")
             + "(on [-r, 0]) and the plant's input to be the initial input"
             + (f" u0 = {', '.join(_num(v) for v in u0)}" if u0 else ""))
    L.append("  (on [-r - tau, 0)).")
    if plant is not None and isinstance(plant.source, ModelFmu):
        L.append(f"  The plant is model {Path(plant.source.model).stem}: the controller "
                 "predicts with that model's f.")
    return L
