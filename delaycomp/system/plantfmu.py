"""A user's plant FMU in the loop: what its modelDescription offers, and the loop around it.

``[plant] fmu = "Plant.fmu"`` in a loop file (``.loopfile``) names any FMI 2.0
co-simulation FMU (C, Python, any exporting tool). ``states`` name the plant outputs that
form the measured state x (in order), ``inputs`` the plant inputs that receive u (in
order), ``parameters`` values set before initialization. The predictor's model comes from
``[controller]``: ``A`` and ``B`` (LTI, with ``K``) or ``model = "file.py"``.

The modelDescription is read here with the standard library only (zip and XML): this layer
knows nothing of FMI calls. Each problem is a one-line ``ParameterError`` naming the
key and the variable. The two delays are built without direct feedthrough whenever their
delay is at least one base step, so a plant whose outputs depend on its inputs at the same
instant (an ``acceleration`` output, say) is no algebraic loop.
"""

from __future__ import annotations

import math
import sys
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, cast
from xml.etree import ElementTree

import numpy as np

from delaycomp.errors import BadFileError, ParameterError
from delaycomp.names import indexed
from delaycomp.system.loop import (
    BuiltinFmu,
    FmuFile,
    Instance,
    Loop,
    ModelFmu,
    Port,
    Timing,
    check_delays,
    check_zoh_delay,
    matrix_params,
    standard_wiring,
    vector_params,
)
from delaycomp.unpack import Budget, measure


@dataclass(frozen=True)
class Variable:
    """A scalar variable of a modelDescription."""

    name: str
    type: str  # Real, Integer, Boolean, String, Enumeration
    causality: str
    variability: str
    start: str | None = None
    #: the ``initial`` attribute as declared (``None`` where absent)
    initial: str | None = None
    #: the ``valueReference`` (``None`` where it is not an integer: ``check_declarations``
    #: refuses that file)
    value_reference: int | None = None


@dataclass(frozen=True)
class FmuInterface:
    """What a loop needs to know of an FMU file, read from its modelDescription."""

    path: Path
    model_name: str
    fmi_version: str
    co_simulation: str | None  # the CS modelIdentifier, None without CS
    model_exchange: str | None  # the ME modelIdentifier, None without ME
    variables: Mapping[str, Variable] = field(default_factory=dict)
    #: the continuous states of Model Exchange, in order (names), and their derivatives
    states: tuple[str, ...] = ()
    derivatives: tuple[str, ...] = ()
    platforms: tuple[str, ...] = ()
    #: each output's dependencies (ModelStructure): the names of the knowns it depends on,
    #: ``None`` where the FMU does not say (then, by FMI 2.0, on every known)
    dependencies: Mapping[str, tuple[str, ...] | None] = field(default_factory=dict)
    #: Model Exchange's ``providesDirectionalDerivative``
    directional: bool = False

    def of(self, causality: str, type_: str = "Real") -> list[str]:
        """The names of the variables of this causality and type, in the modelDescription's
        order."""
        return [v.name for v in self.variables.values()
                if v.causality == causality and v.type == type_]


def platform_folder() -> str:
    """The FMI 2.0 binaries folder of this host (linux64, win64, darwin64)."""
    bits = "64" if sys.maxsize > 2**32 else "32"
    if sys.platform.startswith("win"):
        return f"win{bits}"
    if sys.platform == "darwin":
        return f"darwin{bits}"
    return f"linux{bits}"


def check_declarations(path: Path, variables: Sequence[tuple[str, str, str, object]]
                       ) -> None:
    """Refuse (``BadFileError``, one line) a modelDescription that declares a variable
    name twice, a value reference that is not an integer from 0 to 2^32 - 1, or an input
    that shares its value reference with another variable of its type (an output that is
    an input's alias: setting the input would change what the FMU declares as its own
    output behind the master's back). ``variables``: ``(name, type, causality,
    valueReference)`` in the description's order. Aliases among outputs, locals and
    parameters are FMI 2.0's own and pass (2.2.7: an alias set holds at most one input).

    Examples
    --------
    >>> check_declarations(Path("ok.fmu"), [("x", "Real", "output", "0"),
    ...                                     ("x_alias", "Real", "local", "0")])
    >>> check_declarations(Path("p.fmu"), [("y", "Real", "output", "4"),
    ...                                    ("u", "Real", "input", "4")])
    ... # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.BadFileError: p.fmu: declares output 'y' with the value reference 4 ...
    """
    seen: dict[str, int] = {}
    by_ref: dict[tuple[str, int], list[tuple[str, str]]] = {}
    for i, (name, type_, causality, ref) in enumerate(variables, start=1):
        if name in seen:
            raise BadFileError(path, f"declares the variable {name!r} twice (ScalarVariables "
                                     f"{seen[name]} and {i}): names must be unique")
        seen[name] = i
        try:
            vr = int(str(ref))
        except ValueError:
            vr = -1
        if not 0 <= vr < 2**32:
            raise BadFileError(path, f"declares {name!r} with valueReference = {ref!r}: "
                                     "must be an integer from 0 to 4294967295")
        by_ref.setdefault((type_, vr), []).append((name, causality))
    for (type_, vr), names in by_ref.items():
        inputs = [n for n, c in names if c == "input"]
        if inputs and len(names) > 1:
            other, causality = next((n, c) for n, c in names if n != inputs[0])
            raise BadFileError(path, f"declares {causality} {other!r} with the value "
                                     f"reference {vr} of input {inputs[0]!r} ({type_}): an "
                                     "input may share its value reference with no other "
                                     "variable")


def read_interface(path: str | Path) -> FmuInterface:
    """The ``FmuInterface`` of the FMU file ``path``; a file that is not an FMI 2.0
    FMU raises ``BadFileError`` (one line)."""
    path = Path(path)
    if not path.is_file():
        raise BadFileError(path, "no such FMU file")
    try:
        # within the limits of delaycomp.unpack, as it will be unpacked to run (a zip
        # bomb, its modelDescription.xml included, is refused before anything is read)
        measure(path, Budget(path))
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
            if "modelDescription.xml" not in names:
                raise BadFileError(path, "is not an FMU: it has no modelDescription.xml")
            root = ElementTree.fromstring(zf.read("modelDescription.xml"))
    except zipfile.BadZipFile:
        raise BadFileError(path, "is not an FMU: not a zip archive") from None
    except ElementTree.ParseError as exc:
        raise BadFileError(path, f"has a modelDescription.xml that is not XML: {exc}"
                           ) from None
    version = root.get("fmiVersion", "")
    if version != "2.0":
        raise BadFileError(path, f"is an FMI {version or '?'} FMU: a loop file's plant FMU "
                                 "must be FMI 2.0 (delaycomp's own FMUs run as FMI 3.0 beside "
                                 "it with --fmi 3)")
    cs, me = root.find("CoSimulation"), root.find("ModelExchange")
    variables: dict[str, Variable] = {}
    ordered: list[Variable] = []
    for sv in root.iter("ScalarVariable"):
        typed = next((c for c in sv if c.tag in ("Real", "Integer", "Boolean", "String",
                                                 "Enumeration")), None)
        var = Variable(sv.get("name", ""), typed.tag if typed is not None else "?",
                       sv.get("causality", "local"), sv.get("variability", "continuous"),
                       typed.get("start") if typed is not None else None, sv.get("initial"),
                       _reference(sv.get("valueReference")))
        variables[var.name] = var
        ordered.append(var)
    check_declarations(path, [(v.name, v.type, v.causality, sv.get("valueReference"))
                              for v, sv in zip(ordered, root.iter("ScalarVariable"))])
    states, ders = [], []
    structure = root.find("ModelStructure")
    derivatives = structure.find("Derivatives") if structure is not None else None
    if derivatives is not None:
        for unknown in derivatives:
            der = ordered[int(cast(str, unknown.get("index"))) - 1]
            ders.append(der.name)
            real = cast(ElementTree.Element, next(sv for sv in root.iter("ScalarVariable")
                                                  if sv.get("name") == der.name).find("Real"))
            states.append(ordered[int(cast(str, real.get("derivative"))) - 1].name)
    platforms = tuple(sorted({n.split("/")[1] for n in names
                              if n.startswith("binaries/") and n.count("/") >= 2
                              and not n.endswith("/")}))
    deps: dict[str, tuple[str, ...] | None] = {}
    outputs = structure.find("Outputs") if structure is not None else None
    for unknown in outputs if outputs is not None else ():
        try:
            var = ordered[int(cast(str, unknown.get("index"))) - 1]
            listed = unknown.get("dependencies")
            deps[var.name] = None if listed is None else tuple(
                ordered[int(i) - 1].name for i in listed.split())
        except (ValueError, IndexError):
            raise BadFileError(path, "has a ModelStructure/Outputs entry whose index or "
                                     "dependencies name no ScalarVariable") from None
    return FmuInterface(path, root.get("modelName", ""), version,
                        cs.get("modelIdentifier") if cs is not None else None,
                        me.get("modelIdentifier") if me is not None else None,
                        variables, tuple(states), tuple(ders), platforms, deps,
                        me is not None and me.get("providesDirectionalDerivative") in (
                            "true", "1"))


def _reference(ref: str | None) -> int | None:
    """A ``valueReference`` attribute as an integer, ``None`` where it is none."""
    try:
        return int(cast(str, ref))
    except (TypeError, ValueError):
        return None


def _names(where: str, value) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not (isinstance(value, (list, tuple)) and value
            and all(isinstance(v, str) and v for v in value)):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be a list of "
                             "variable names")
    dup = next((v for v in value if list(value).count(v) > 1), None)
    if dup is not None:
        raise ParameterError(f"{where}: variable {dup!r} is named twice")
    return list(value)


def check_mapping(fmu: FmuInterface, states, inputs, parameters: Mapping | None,
                  where: str = "plant", start: Mapping | None = None
                  ) -> tuple[list[str], list[str], dict]:
    """Check ``states``, ``inputs``, ``parameters`` and the ``start`` values (of variables
    that are not parameters: ``start_variables``) against the FMU; return the names as
    lists and the values to set before initialization, parameters and start values in one
    table (numbers, booleans or strings)."""
    name = fmu.path.name
    if fmu.co_simulation is None:
        raise ParameterError(f"{where}.fmu = {name!r} is not allowed: it has no "
                             "co-simulation interface (FMI 2.0 CS)")
    here = platform_folder()
    if here not in fmu.platforms:
        have = ", ".join(fmu.platforms) or "none (sources only)"
        raise ParameterError(f"{where}.fmu = {name!r} is not allowed: it has no binary for "
                             f"{here} (binaries: {have})")
    states = _names(f"{where}.states", states)
    inputs = _names(f"{where}.inputs", inputs)
    for key, names, causality in (("states", states, "output"), ("inputs", inputs, "input")):
        for s in names:
            var = fmu.variables.get(s)
            if var is None or var.causality != causality or var.type != "Real":
                what = "no variable" if var is None else f"a {var.type} {var.causality}"
                have = ", ".join(fmu.of(causality)) or "it has none"
                raise ParameterError(f"{where}.{key}: {s!r} is {what} of {name}: must be a "
                                     f"Real {causality} ({have})")
    values = {}
    if parameters is not None and not isinstance(parameters, Mapping):
        raise ParameterError(f"{where}.parameters is not allowed: must be a table "
                             "{name = value}")
    settable = [v.name for v in fmu.variables.values() if v.causality == "parameter"
                and v.variability in ("fixed", "tunable")]
    for pname, value in (parameters or {}).items():
        var = fmu.variables.get(pname)
        if var is None or pname not in settable:
            raise ParameterError(f"{where}.parameters: {pname!r} is not a settable parameter "
                                 f"of {name}: allowed are {', '.join(settable) or 'none'}")
        values[pname] = _value(f"{where}.parameters", pname, var, value)
    if start is not None and not isinstance(start, Mapping):
        raise ParameterError(f"{where}.start is not allowed: must be a table {{name = value}}")
    startable = start_variables(fmu, inputs)
    for vname, value in (start or {}).items():
        var = fmu.variables.get(vname)
        if var is None or vname not in startable:
            why = ""
            if var is not None and var.causality == "parameter":
                why = f" ({vname!r} is a parameter: give it in {where}.parameters)"
            elif var is not None and vname in inputs:
                why = f" ({vname!r} is driven by the loop: it is in {where}.inputs)"
            elif var is not None and var.initial == "approx":
                why = (f" ({vname!r} has initial = \"approx\": a guess the FMU's own "
                       "initialization may change, not a value a master sets)")
            raise ParameterError(f"{where}.start: {vname!r} is not a start value that the "
                                 f"master may set in {name}{why}: allowed are "
                                 f"{', '.join(startable) or 'none'}")
        values[vname] = _value(f"{where}.start", vname, var, value)
    return states, inputs, values


def start_variables(fmu: FmuInterface, inputs: Sequence[str] = ()) -> list[str]:
    """The variables besides parameters whose start value a master sets before the FMU's
    initialization (FMI 2.0, 4.2.4: ``initial = "exact"`` and not constant, e.g. the
    continuous states a Modelica tool exports as locals; and the inputs), less ``inputs``
    (those the loop drives)."""
    return [v.name for v in fmu.variables.values()
            if v.causality not in ("parameter", "calculatedParameter", "independent")
            and v.variability != "constant" and v.name not in inputs
            and (v.initial == "exact" or v.causality == "input")]


def _value(where: str, vname: str, var: Variable, value):
    """``value`` for the FMU variable ``var``, checked against its type."""
    if var.type == "Real":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value)):
            raise ParameterError(f"{where}: {vname} = {value!r} is not allowed: must be a "
                                 "finite number (Real)")
        return float(value)
    if var.type in ("Integer", "Enumeration"):
        if isinstance(value, bool) or not (isinstance(value, int) or (
                isinstance(value, float) and value.is_integer())):
            raise ParameterError(f"{where}: {vname} = {value!r} is not allowed: must be an "
                                 "integer")
        return int(value)
    if var.type == "Boolean":
        if not isinstance(value, bool):
            raise ParameterError(f"{where}: {vname} = {value!r} is not allowed: must be true "
                                 "or false")
        return value
    if not isinstance(value, str):
        raise ParameterError(f"{where}: {vname} = {value!r} is not allowed: must be a string")
    return value


def state_of(fmu: FmuInterface, output: str) -> str | None:
    """The continuous state that the output ``output`` of ``fmu`` is, if any.

    An output is a continuous state when it is the variable that a derivative's
    ``derivative`` attribute names (the Reference FMUs' ``x0`` beside ``der(x0)``), or an
    alias of it: a Real of the same value reference (FMI 2.0, 2.2.7; an alias set holds
    one value).

    Parameters
    ----------
    fmu : FmuInterface
        The FMU, as ``read_interface`` reads it.
    output : str
        The name of one of its variables.

    Returns
    -------
    str or None
        The name of the state (``fmu.states``), ``None`` where ``output`` is none.

    Examples
    --------
    >>> fmu = FmuInterface(Path("VanDerPol.fmu"), "VanDerPol", "2.0", "VanDerPol",
    ...                    "VanDerPol", {"x0": Variable("x0", "Real", "output",
    ...                                                 "continuous", value_reference=0),
    ...                                  "y": Variable("y", "Real", "output",
    ...                                                "continuous", value_reference=0),
    ...                                  "z": Variable("z", "Real", "output",
    ...                                                "continuous", value_reference=5)},
    ...                    states=("x0",), derivatives=("der(x0)",))
    >>> state_of(fmu, "x0"), state_of(fmu, "y"), state_of(fmu, "z")
    ('x0', 'x0', None)
    """
    if output in fmu.states:
        return output
    var = fmu.variables.get(output)
    if var is None or var.type != "Real" or var.value_reference is None:
        return None
    return next((x for x in fmu.states
                 if (state := fmu.variables.get(x)) is not None and state.type == "Real"
                 and state.value_reference == var.value_reference), None)


def check_output_map(fmu: FmuInterface, states: Sequence[str],
                     where: str = "controller.predictor") -> None:
    """Refuse outputs that cannot determine the FMU's continuous states, as far as its
    modelDescription tells (``predictor = "plant-fmu"``).

    Refused, in one line that says what to give instead: an FMU without continuous
    states, fewer outputs than states, an output with direct feedthrough from an input,
    or a state that no named output determines. An output determines the state that it is
    (``state_of``: the Reference FMUs declare such an output with ``dependencies=""``,
    the other knowns it depends on being none) and the states its ``dependencies`` list
    (ModelStructure/Outputs); an output without ``dependencies`` may depend on every
    known (FMI 2.0, 2.2.8), so the check cannot tell and leaves it to the controller. An
    output that is no state and depends on no state (``dependencies=""``, a constant as
    far as the description says) determines none.

    Parameters
    ----------
    fmu : FmuInterface
        The plant FMU, as ``read_interface`` reads it.
    states : sequence of str
        The outputs measured (``plant.states``), already checked to be Real outputs
        (``check_mapping``).
    where : str
        The key named in the messages.

    Raises
    ------
    ParameterError
        One line, naming the outputs and the state concerned.

    Notes
    -----
    Whether the map is invertible where the loop runs is checked by the controller on its
    Jacobian (``delaycomp.maths.outputmap.check_rank``).

    Examples
    --------
    >>> real = dict(type="Real", causality="output", variability="continuous")
    >>> fmu = FmuInterface(Path("VanDerPol.fmu"), "VanDerPol", "2.0", "VanDerPol",
    ...                    "VanDerPol", {n: Variable(n, value_reference=i, **real)
    ...                                  for i, n in enumerate(["x0", "x1", "c"])},
    ...                    states=("x0", "x1"), derivatives=("der(x0)", "der(x1)"),
    ...                    dependencies={"x0": (), "x1": (), "c": ()})
    >>> check_output_map(fmu, ["x0", "x1"])
    >>> check_output_map(fmu, ["x0", "c"])   # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: ... no output in plant.states (x0, c) is or depends on ...
    """
    name, xs = fmu.path.name, list(fmu.states)
    head = f'{where} = "plant-fmu" is not allowed'
    instead = "or give A and B (or model) for the predictor"
    if not xs:
        raise ParameterError(f"{head}: {name} declares no continuous states "
                             f"(ModelStructure/Derivatives): nothing to predict; {instead}")
    if len(states) < len(xs):
        raise ParameterError(
            f"{head}: plant.states names {len(states)} output(s) ({', '.join(states)}) for "
            f"the {len(xs)} continuous states of {name} ({', '.join(xs)}): the outputs "
            f"cannot determine the states; name at least {len(xs)} outputs that do, "
            f"{instead}")
    covered: set[str] | None = set()
    for s in states:
        deps = fmu.dependencies.get(s)
        if deps is None:  # not declared: it may depend on anything (FMI 2.0, 2.2.8)
            covered = None
            continue
        fed = [d for d in deps if fmu.variables[d].causality == "input"]
        if fed:
            raise ParameterError(
                f"{head}: output {s!r} of {name} depends on the input {fed[0]!r} at the "
                "same instant (direct feedthrough, ModelStructure): each output in "
                f"plant.states must be a function of the FMU's states alone; name another "
                f"output, {instead}")
        if covered is not None:
            # the states it depends on, and the state it is (whatever its list says)
            covered |= set(deps) & set(xs)
            if (state := state_of(fmu, s)) is not None:
                covered.add(state)
    missing = [x for x in xs if covered is not None and x not in covered]
    if missing:
        raise ParameterError(
            f"{head}: no output in plant.states ({', '.join(states)}) is or depends on the "
            f"state {missing[0]!r} of {name} (ModelStructure), so the outputs cannot "
            f"determine it; name an output that does, {instead}")


def _delay_source(n: int, delay: float, h: float) -> BuiltinFmu:
    """The delay FMU for ``n`` channels: without direct feedthrough when the delay is at
    least one base step (``delay`` is on the grid: checked before)."""
    if delay >= h * (1 - 1e-9):
        return BuiltinFmu("delay", {"feedthrough": False, "n": n})
    return BuiltinFmu("delay", {"n": n})


def _zoh_of(model, controller_parameters: Mapping | None,
            pad: bool = False) -> Literal["hold", "pad"] | None:
    """How the controller constrains ``tau`` (``check_delays``): the LTI controller's and
    a model's under zero-order hold, unless it pads (``pad``, the LTI controller's;
    ``controller_parameters["pad"]``, a model's)."""
    if model is None:
        return None if pad else "pad"
    from delaycomp.maths.model import load_model

    if load_model(model).control != "zoh" or (controller_parameters or {}).get("pad", False):
        return None
    return "pad"


def fmu_plant_loop(fmu_path, states: Sequence[str], inputs: Sequence[str],
                   fmu_parameters: Mapping | None, T: float, r: float, tau: float, N: int, x0,
                   u0=None,
                   *, A=None, B=None, K=None, mode: str = "compensated", model=None,
                   controller_parameters: Mapping | None = None,
                   r_true: float | None = None, tau_true: float | None = None,
                   name: str = "loop", title: str = "",
                   stop_time: float | None = None, start: Mapping | None = None,
                   pad: bool = False) -> Loop:
    """The loop plant FMU (as it is) -> measurement delay -> controller -> input delay.

    The controller is delaycomp's LTI controller with the model ``A``, ``B`` and gain
    ``K`` (``u = K x``, the paper's sign; ``pad``: a ``tau`` that is no multiple of ``T``
    padded up to one, Remark 3.3(b), the controller delaying its output by the
    difference), or the controller FMU of the model file
    ``model`` (with ``controller_parameters``: its parameters and settings, as
    ``model_loop`` takes them). ``x0`` is the history of the measured
    state on ``[-r, 0]`` (the measurement delay's initial output); the FMU's own initial
    state is set by its parameters and the ``start`` values of its other variables (its
    hidden continuous states, say: ``start_variables``); the master checks that the
    FMU's outputs ``states`` equal ``x0`` once it is initialized (``Loop.initial``).
    Recorded: the states, the controller's outputs and what the plant receives (the input
    delay's outputs, in columns named by the FMU's own inputs: ``plant.force``).
    """
    fmu = read_interface(fmu_path)
    states, inputs, values = check_mapping(fmu, states, inputs, fmu_parameters, start=start)
    n, m = len(states), len(inputs)
    x0, u0 = histories(x0, u0, states, inputs)
    timing = Timing(T, N)
    r_loop, tau_loop = check_delays(timing, r, tau, r_true, tau_true,
                                    zoh=_zoh_of(model, controller_parameters, pad))
    if model is None:
        ctrl, ctrl_in, ctrl_out = _lti_controller(A, B, K, states, inputs, T, r, tau, mode,
                                                  u0, pad)
    else:
        ctrl, ctrl_in, ctrl_out = _model_controller(model, controller_parameters, n, m, T,
                                                    r, tau, N, x0, u0)
    instances = (
        Instance("plant", "plant", FmuFile(Path(fmu_path)), values),
        Instance("meas_delay", "meas_delay", _delay_source(n, r_loop, timing.h),
                 {"delay": r_loop, **vector_params("u0", x0)}),
        ctrl,
        Instance("input_delay", "input_delay", _delay_source(m, tau_loop, timing.h),
                 {"delay": tau_loop, **vector_params("u0", u0)}),
    )
    connections = standard_wiring(states, ctrl_in, ctrl_out, inputs)
    # what the plant receives, under the FMU's own input names: the input delay's outputs
    received = [Port("input_delay", o) for o in indexed("y", m)]
    recorded = tuple([Port("plant", s) for s in states]
                     + [Port("controller", u) for u in ctrl_out] + received)
    initial = tuple((Port("plant", s), float(v)) for s, v in zip(states, x0))
    labels = tuple((p, f"plant.{u}") for p, u in zip(received, inputs))
    return Loop(instances, connections, timing, recorded, name, title, stop_time,
                initial=initial, labels=labels)


def histories(x0, u0, states: list[str], inputs: list[str]
              ) -> tuple[np.ndarray, np.ndarray]:
    """The initial histories x0 (one value per state) and u0 (per input; default 0),
    checked: a wrong length is refused naming the states or inputs."""
    x0 = np.asarray(x0, dtype=float).ravel()
    u0 = np.zeros(len(inputs)) if u0 is None else np.asarray(u0, dtype=float).ravel()
    if x0.shape != (len(states),):
        raise ParameterError(f"parameter x0 has {x0.size} values: must have one per state "
                             f"({', '.join(states)})")
    if u0.shape != (len(inputs),):
        raise ParameterError(f"parameter u0 has {u0.size} values: must have one per input "
                             f"({', '.join(inputs)})")
    return x0, u0


def _lti_controller(A, B, K, states: list[str], inputs: list[str], T: float, r: float,
                    tau: float, mode: str, u0: np.ndarray, pad: bool = False
                    ) -> tuple[Instance, list[str], list[str]]:
    """delaycomp's LTI controller of ``A``, ``B``, ``K`` (shapes checked), its inputs and
    outputs; ``pad``: its ``pad`` parameter (Remark 3.3(b))."""
    n, m = len(states), len(inputs)
    A, B, K = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B, K))
    if A.shape != (n, n):
        raise ParameterError(f"controller.A has shape {A.shape}: must be n x n = {n} x {n} "
                             f"(one row per state: {', '.join(states)})")
    if B.shape != (n, m):
        raise ParameterError(f"controller.B has shape {B.shape}: must be n x m = {n} x {m} "
                             f"(one column per input: {', '.join(inputs)})")
    if K.shape != (m, n):
        raise ParameterError(f"controller.K has shape {K.shape}: must be m x n = {m} x {n} "
                             "(u = K x)")
    if not pad:
        check_zoh_delay(tau, T, padding=True)
    ctrl = Instance("controller", "controller", BuiltinFmu("controller", {"n": n, "m": m}),
                    {"T": T, "r": r, "tau": tau, "mode": mode, **matrix_params("A", A),
                     **matrix_params("B", B), **matrix_params("K", K),
                     **vector_params("u0", u0),
                     **({"pad": True} if pad else {})})  # unpadded: the parameters as before
    # no LtiDesign: the exact analyses (lifted loop, critical delay) would take A, B
    # for the plant, and the plant here is the FMU
    return ctrl, indexed("y", n), indexed("u", m)


def _model_controller(model, controller_parameters: Mapping | None, n: int, m: int,
                      T: float, r: float, tau: float, N: int, x0: np.ndarray,
                      u0: np.ndarray) -> tuple[Instance, list[str], list[str]]:
    """The controller FMU of the model file ``model`` (its n and m checked against the
    plant's), its inputs and outputs."""
    from delaycomp.maths.model import load_model

    mdl = load_model(model)
    if (mdl.n, mdl.m) != (n, m):
        raise ParameterError(f"controller.model {Path(model).name} has n = {mdl.n} "
                             f"states and m = {mdl.m} inputs: plant.states names {n}, "
                             f"plant.inputs {m}")
    params = dict(controller_parameters or {})
    if mdl.control == "zoh" and not params.get("pad", False):
        check_zoh_delay(tau, T, padding=True)
    ctrl = Instance("controller", "controller",
                    ModelFmu("model_controller", Path(model)),
                    {"T": T, "r": r, "tau": tau, "N": N, **vector_params("u0", u0),
                     **vector_params("z0", x0), **params})
    return ctrl, [f"y_{s}" for s in mdl.states], list(mdl.inputs)


def check_tolerance(value, where: str = "plant.tolerance") -> float:
    """``[plant] tolerance`` of a plant FMU checked: a finite number in (0, 1) (what FMI's
    ``fmi2SetupExperiment`` takes as a relative tolerance), else a one-line
    ``ParameterError`` naming ``where``.

    Examples
    --------
    >>> check_tolerance(1e-8)
    1e-08
    >>> check_tolerance(1.0)   # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: plant.tolerance = 1.0 is not allowed: must be a ...
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and 0 < value < 1):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be a finite number "
                             "in (0, 1)")
    return float(value)


def with_tolerance(loop: Loop, tolerance: float | None) -> Loop:
    """``loop`` whose plant FMU file gets the relative ``tolerance`` at
    ``fmi2SetupExperiment`` (``toleranceDefined = true``; checked by
    ``check_tolerance``); ``None``: the loop as it is (no tolerance defined, the FMU's
    own default)."""
    if tolerance is None:
        return loop
    tolerance = check_tolerance(tolerance)
    plant = loop.by_role("plant")
    if plant is None or not isinstance(plant.source, FmuFile):
        raise ParameterError("plant.tolerance is not allowed here: the plant is not an FMU "
                             "file")
    source = FmuFile(plant.source.path, tolerance)
    return loop.with_instances(replace(i, source=source) if i is plant else i
                               for i in loop.instances)


def undriven_inputs(loop: Loop) -> dict[str, list[Variable]]:
    """The inputs of each FMU file of ``loop`` (another tool's FMU) that no connection
    drives, by instance name, in the modelDescription's order (instances with none are
    left out): they keep their start values for the whole run (a load torque, a brake
    flag the loop does not touch)."""
    driven = {(c.dst.instance, c.dst.variable) for c in loop.connections}
    found: dict[str, list[Variable]] = {}
    for inst in loop.instances:
        if not isinstance(inst.source, FmuFile):
            continue
        free = [v for v in read_interface(inst.source.path).variables.values()
                if v.causality == "input" and (inst.name, v.name) not in driven]
        if free:
            found[inst.name] = free
    return found


def undriven_notes(loop: Loop) -> list[str]:
    """One note per FMU file of ``loop`` with inputs no connection drives, naming them
    with their start values (what they keep): ``plant inputs not driven by the loop keep
    their start values: load.tau = 0, brake.engaged = false``."""
    return [f"{name} inputs not driven by the loop keep their start values: "
            + ", ".join(f"{v.name} = {v.start}" if v.start is not None
                        else f"{v.name} (no start value)" for v in free)
            for name, free in undriven_inputs(loop).items()]
