"""Reading SSP 1.0 back into a loop: an SSD and its SSVs (``read_system``), an SSP
written by another tool (``Foreign``), parameter sets applied to a loop
(``apply_sets``), the check against the SSP XSDs (``validate``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

from lxml import etree

from delaycomp.errors import ParameterError, SspError
from delaycomp.formats.ssp.common import (
    DC_ANNOTATION,
    DEFAULT_SET,
    NSMAP,
    SystemInfo,
    config_in,
    native_parameters,
    parse_value,
    parse_xml,
    required_attr,
    ssv_type,
    tag,
)
from delaycomp.system import (
    ROLES,
    BuiltinFmu,
    Connection,
    FmuFile,
    Instance,
    Loop,
    ModelFmu,
    Port,
    Role,
    Source,
    Timing,
)


@dataclass(frozen=True)
class System:
    """An SSD read back: the loop, what else it says, and each instance's FMU file."""

    spec: Loop
    info: SystemInfo
    #: instance -> the component's ``source`` (relative to the SSD)
    sources: dict[str, str]


def read_ssv(path: str | Path) -> tuple[str, dict]:
    """Name and parameters (typed values) of the SSV parameter set at ``path``."""
    path = Path(path)
    root = parse_xml(path)
    if root.tag != tag("ssv:ParameterSet"):
        raise SspError(f"{path.name}: not an SSV 1.0 parameter set (root {root.tag})")
    params = {}
    for p in root.iterfind("ssv:Parameters/ssv:Parameter", NSMAP):
        name = required_attr(p, "name", path.name)
        value = next(iter(p), None)
        if value is None or not isinstance(value.tag, str):
            raise SspError(f"{path.name}: parameter {name!r} has no value")
        kind = etree.QName(value).localname
        if kind not in ("Real", "Integer", "Boolean", "String"):
            raise SspError(f"{path.name}: parameter {name!r} has unsupported type {kind}")
        try:
            params[name] = parse_value(kind, required_attr(value, "value", f"{path.name}: {name}"))
        except ValueError:
            raise SspError(f"{path.name}: parameter {name!r}: bad {kind} value "
                           f"{value.get('value')!r}") from None
    return required_attr(root, "name", path.name), params


#: largest dc:Master N read from an SSD (base steps per sampling period)
MAX_N = 10**6


def _inside(ssd_path: Path, source: str, where: str) -> str:
    """``source`` if it names a file under the SSD's folder; else a refusal (an absolute
    path, a URI, ``../`` climbing out)."""
    if not source or "://" in source or source.startswith(("/", "\\")) or (
            len(source) > 1 and source[1] == ":"):
        raise SspError(f"{where}: source {source!r} is not allowed: must be a path relative "
                       "to the SSD, inside the archive")
    root = ssd_path.parent.resolve()
    if not (root / source).resolve().is_relative_to(root):
        raise SspError(f"{where}: source {source!r} is not allowed: it leaves the archive")
    return source


@dataclass(frozen=True)
class Foreign:
    """Master settings and roles for an SSP written by another tool (no delaycomp
    annotations): the sampling period ``T``, base steps per period ``N`` and the roles of
    components by name (``--role NAME=ROLE``). A role not given is taken from the
    component's name when that is a role name, else found from the connections: walking
    the loop from the plant, four components are plant, measurement delay, controller and
    input delay, two are plant and controller."""

    T: float | None = None
    N: int | None = None
    roles: Mapping[str, str] = field(default_factory=dict)


def _infer_roles(where: str, names: list[str], roles: dict[str, str | None],
                 connections: list[Connection]) -> dict[str, Role]:
    """Fill unknown roles by walking the component cycle from the plant (see Foreign)."""
    unknown = [n for n in names if roles[n] is None]
    if not unknown:
        # every role is known, and each a role of ROLES (read_system checks them)
        return cast("dict[str, Role]", dict(roles))
    how = (f"name its role with --role {unknown[0]}=ROLE ({', '.join(ROLES)})")
    plant = next((n for n, r in roles.items() if r == "plant"), None)
    if plant is None:
        raise SspError(f"{where}: component {unknown[0]} has no role and no component is "
                       f"known as the plant: {how}")
    succ: dict[str, set[str]] = {n: set() for n in names}
    for c in connections:
        if c.src.instance != c.dst.instance:
            succ[c.src.instance].add(c.dst.instance)
    cycle, node = [plant], plant
    while True:
        nxt = succ[node]
        if len(nxt) != 1:
            raise SspError(f"{where}: the roles cannot be found from the connections "
                           f"({node} feeds {len(nxt)} components, a loop feeds one): {how}")
        node = next(iter(nxt))
        if node == plant:
            break
        if node in cycle:
            raise SspError(f"{where}: the connections from {plant} do not come back to it: "
                           f"{how}")
        cycle.append(node)
    order = {4: ROLES, 2: ("plant", "controller")}.get(len(cycle))
    if order is None or len(cycle) != len(names):
        raise SspError(f"{where}: a loop of {len(cycle)} of {len(names)} components: the "
                       f"roles follow from the connections for 4 (plant, meas_delay, "
                       f"controller, input_delay) or 2 (plant, controller): {how}")
    found = dict(zip(cycle, order))
    for n in names:
        if roles[n] is not None and roles[n] != found[n]:
            raise SspError(f"{where}: component {n} is named {roles[n]}, but the "
                           f"connections make it the {found[n]}")
    return found


def read_system(ssd_path: str | Path, foreign: Foreign | None = None) -> System:
    """Read an SSD written by ``write_system`` (and its SSVs) back into a loop.

    With ``foreign`` an SSD without delaycomp's annotations is read too (an SSP 1.0 of
    another tool): its master settings and roles come from ``foreign`` (``Foreign``),
    its components are FMU files as they are, and the recorded signals are the plant's and
    the controller's connected outputs."""
    ssd_path = Path(ssd_path)
    where = ssd_path.name
    root, system, master = _open_ssd(ssd_path, foreign)
    given_roles = _given_roles(foreign)
    described = ({c.get("element"): c for c in master.iterfind("dc:Component", NSMAP)}
                 if master is not None else {})
    roles: dict[str, str | None] = {}
    # each component's name, source and parameters (its role is known after the loop)
    components: list[tuple[str, Source, dict]] = []
    sources: dict[str, str] = {}
    set_names: set[str] = set()
    for comp in system.iterfind("ssd:Elements/ssd:Component", NSMAP):
        name, role, source, params = _read_component(ssd_path, comp, described, foreign,
                                                     given_roles, sources, set_names)
        roles[name] = role
        components.append((name, source, params))
    for name in given_roles:
        if name not in roles:
            raise SspError(f"--role {name}=...: {where} has no component {name!r}: its "
                           f"components are {', '.join(roles)}")
    connections = _read_connections(system, where)
    found = _infer_roles(where, list(roles), roles, connections)
    instances = [Instance(name, found[name], source, params)
                 for name, source, params in components]
    recorded = _recorded(master, found, connections, where)
    labels = [] if master is None else [
        (Port(r.get("element", ""), r.get("connector", "")), r.get("name", ""))
        for r in master.iterfind("dc:Record", NSMAP) if r.get("name")]
    T, N = _master_timing(master, foreign, where)
    info = _system_info(root, system, master, set_names, where)
    try:
        loop = Loop(tuple(instances), tuple(connections), Timing(T, N), tuple(recorded),
                    info.name, info.description, labels=tuple(labels))
    except ParameterError as exc:
        raise SspError(f"{where}: {exc}") from None
    return System(loop, info, sources)


def _open_ssd(ssd_path: Path, foreign: Foreign | None
              ) -> tuple[etree._Element, etree._Element, etree._Element | None]:
    """The SSD's root, its ssd:System and its dc:Master (None for a foreign SSD)."""
    root = parse_xml(ssd_path)
    where = ssd_path.name
    if root.tag != tag("ssd:SystemStructureDescription"):
        raise SspError(f"{where}: not an SSP 1.0 system structure (root {root.tag})")
    system = root.find("ssd:System", NSMAP)
    if system is None:
        raise SspError(f"{where}: no ssd:System")
    master = root.find(f"ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation"
                       f"[@type='{DC_ANNOTATION}']/dc:Master", NSMAP)
    if master is None and (foreign is None or foreign.T is None or foreign.N is None):
        raise SspError(f"{where}: no {DC_ANNOTATION} annotation with dc:Master: not a "
                       "delaycomp system (to run an SSP of another tool give the master "
                       "settings: --period T --steps N)")
    return root, system, master


def _given_roles(foreign: Foreign | None) -> dict[str, str]:
    """The roles given with ``--role``, each checked to be a role of ROLES."""
    given_roles = dict(foreign.roles) if foreign is not None else {}
    for cname, crole in given_roles.items():
        if crole not in ROLES:
            raise SspError(f"--role {cname}={crole}: role {crole!r} is not allowed: allowed "
                           f"are {', '.join(ROLES)}")
    return given_roles


def _read_component(ssd_path: Path, comp: etree._Element, described: dict,
                    foreign: Foreign | None, given_roles: dict[str, str],
                    sources: dict[str, str], set_names: set[str]
                    ) -> tuple[str, str | None, Source, dict]:
    """Name, role (None: to be found), source and parameters of one ssd:Component; its
    file goes into ``sources``, the names of its parameter sets into ``set_names``."""
    where = ssd_path.name
    name = required_attr(comp, "name", where)
    sources[name] = _inside(ssd_path,
                            required_attr(comp, "source", f"{where}: component {name}"),
                            f"{where}: component {name}")
    fmu = described.get(name)
    if fmu is None:  # an archive of an earlier layout: the description in the component
        fmu = comp.find(f"ssd:Annotations/ssc:Annotation[@type='{DC_ANNOTATION}']/dc:Fmu",
                        NSMAP)
    if fmu is None and foreign is None:
        raise SspError(f"{where}: component {name} has no dc:Component (nor dc:Fmu) "
                       "annotation")
    role, choices = _role_and_choices(where, name, fmu, given_roles)
    source = _component_source(ssd_path, name, fmu, sources[name])
    params: dict = {}
    for binding in comp.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NSMAP):
        bsource = _inside(ssd_path,
                          required_attr(binding, "source", f"{where}: component {name}"),
                          f"{where}: component {name}")
        set_name, values = read_ssv(ssd_path.parent / bsource)
        set_names.add(set_name)
        params.update(values)
    params = native_parameters(params, choices, f"{where}: component {name}")
    return name, role, source, params


def _role_and_choices(where: str, name: str, fmu: etree._Element | None,
                      given_roles: dict[str, str]) -> tuple[str | None, dict]:
    """A component's role (None when neither given nor described) and its choices."""
    choices: dict = {}
    if fmu is None:
        return given_roles.get(name) or (name if name in ROLES else None), choices
    try:
        choices = {k: tuple(v)
                   for k, v in json.loads(fmu.get("choices", "{}")).items()}
    except (json.JSONDecodeError, AttributeError, TypeError, RecursionError):
        raise SspError(f"{where}: component {name}: choices is not a JSON object of "
                       "lists (or is nested too deeply)") from None
    # archives before roles named instances by role
    role = given_roles.get(name) or fmu.get("role") or name
    if role not in ROLES:
        raise SspError(f"{where}: component {name} has role {role!r}: allowed are "
                       f"{', '.join(ROLES)}")
    return role, choices


def _component_source(ssd_path: Path, name: str, fmu: etree._Element | None,
                      rel: str) -> Source:
    """What a component runs: its dc:Fmu's kind and config, else its FMU file ``rel``
    (with the ``tolerance`` of its dc:Component, where it has one)."""
    kind = fmu.get("kind") if fmu is not None else None
    if kind is None:
        tol = fmu.get("tolerance") if fmu is not None else None
        if tol is not None:
            from delaycomp.system.plantfmu import check_tolerance

            try:
                value = float(tol)
            except ValueError:
                value = tol
            try:
                tol = check_tolerance(value, f"component {name} tolerance")
            except ParameterError as exc:
                raise SspError(f"{ssd_path.name}: {exc}") from None
        return FmuFile(ssd_path.parent / rel, tol)
    try:
        config = config_in(json.loads(required_attr(fmu, "config",
                                                    f"{ssd_path.name}: {name}")))
    except (json.JSONDecodeError, RecursionError):
        raise SspError(f"{ssd_path.name}: component {name}: dc:Fmu config is not JSON "
                       "(or is nested too deeply)") from None
    return (ModelFmu(kind, Path(config["model"])) if "model" in config
            else BuiltinFmu(kind, config))


def _read_connections(system: etree._Element, where: str) -> list[Connection]:
    """The ssd:Connections of ``system``."""
    connections = []
    for c in system.iterfind("ssd:Connections/ssd:Connection", NSMAP):
        ends = [required_attr(c, a, f"{where}: connection") for a in
                ("startElement", "startConnector", "endElement", "endConnector")]
        connections.append(Connection(Port(ends[0], ends[1]), Port(ends[2], ends[3])))
    return connections


def _recorded(master: etree._Element | None, found: dict[str, Role],
              connections: list[Connection], where: str) -> list[Port]:
    """The dc:Record ports; for a foreign SSD the plant's and controller's outputs."""
    if master is not None:
        return [Port(required_attr(r, "element", where), required_attr(r, "connector", where))
                for r in master.iterfind("dc:Record", NSMAP)]
    by_role = {role: name for name, role in found.items()}
    return list(dict.fromkeys(
        c.src for role in ("plant", "controller") for c in connections
        if c.src.instance == by_role.get(role)))


def _master_timing(master: etree._Element | None, foreign: Foreign | None,
                   where: str) -> tuple[float, int]:
    """The sampling period T and base steps N, from ``foreign`` else dc:Master, checked."""
    try:
        if foreign is not None and foreign.T is not None and foreign.N is not None:
            T, N = float(foreign.T), foreign.N
        else:
            T, N = float(required_attr(master, "T", where)), int(required_attr(master, "N", where))
    except ValueError:
        raise SspError(f"{where}: dc:Master T and N must be numbers") from None
    if not (math.isfinite(T) and T > 0):
        raise SspError(f"{where}: dc:Master T = {T!r} is not allowed: must be a finite "
                       "number > 0")
    if not 1 <= N <= MAX_N:
        raise SspError(f"{where}: dc:Master N = {N!r} is not allowed: must be an integer "
                       f"from 1 to {MAX_N}")
    return T, N


def _system_info(root: etree._Element, system: etree._Element,
                 master: etree._Element | None, set_names: set[str],
                 where: str) -> SystemInfo:
    """Name, description, stop time (checked) and parameter set of the SSD."""
    exp = root.find("ssd:DefaultExperiment", NSMAP)
    stop = exp.get("stopTime") if exp is not None else None
    try:
        stop_time = float(stop) if stop is not None else None
    except ValueError:
        raise SspError(f"{where}: stopTime {stop!r} is not a number") from None
    if stop_time is not None and not (math.isfinite(stop_time) and stop_time >= 0):
        raise SspError(f"{where}: stopTime = {stop!r} is not allowed: must be a finite "
                       "number >= 0")
    set_name = next(iter(set_names), DEFAULT_SET)
    if master is not None:
        return SystemInfo(master.get("name", root.get("name", "")),
                          system.get("description", ""), stop_time,
                          master.get("parameterSet", set_name))
    return SystemInfo(root.get("name", ""), system.get("description", ""), stop_time,
                      set_name)


def _schema(name: str) -> etree.XMLSchema:
    import fmpy

    return etree.XMLSchema(etree.parse(str(Path(fmpy.__file__).parent / "ssp" / "schema"
                                           / name)))


def validate(path: str | Path) -> list[str]:
    """Errors of an SSD or SSV against fmpy's SSP 1.0 XSDs (empty when valid)."""
    path = Path(path)
    root = parse_xml(path)
    name = {tag("ssd:SystemStructureDescription"): "SystemStructureDescription.xsd",
            tag("ssv:ParameterSet"): "SystemStructureParameterValues.xsd"}.get(root.tag)
    if name is None:
        return [f"{path.name}: neither an SSD nor an SSV (root {root.tag})"]
    schema = _schema(name)
    if schema.validate(root.getroottree()):
        return []
    return [f"{path.name}:{e.line}: {e.message}" for e in schema.error_log]


def _fmu_parameter_type(fmu: Path, name: str) -> str | None:
    from fmpy import read_model_description

    for v in read_model_description(str(fmu)).modelVariables:
        if v.name == name and v.causality == "parameter":
            return {"Real": "Real", "Integer": "Integer", "Boolean": "Boolean",
                    "String": "String", "Enumeration": "Integer"}[v.type]
    return None


def apply_sets(spec: Loop, assignments: list[str], fmus: dict[str, Path]) -> Loop:
    """``spec`` with ``instance.parameter=value`` assignments applied to FMU parameters.

    The value is parsed as the parameter's type (from the SSV, else the FMU's
    modelDescription); an unknown instance or parameter, or a bad value, raises
    ``SspError``.
    """
    params = {i.name: dict(i.parameters) for i in spec.instances}
    for text in assignments:
        left, sep, value = text.partition("=")
        inst, dot, pname = left.strip().partition(".")
        if not sep or not dot or not pname:
            raise SspError(f"--set {text!r}: an SSP takes instance.parameter=VALUE")
        if inst not in params:
            raise SspError(f"--set {text!r}: no instance {inst!r}: allowed are "
                           f"{', '.join(params)}")
        kind = (ssv_type(params[inst][pname]) if pname in params[inst]
                else _fmu_parameter_type(fmus[inst], pname))
        if kind is None:
            raise SspError(f"--set {text!r}: {inst} has no parameter {pname!r}")
        try:
            parsed = parse_value(kind, value.strip().lower() if kind == "Boolean"
                                 else value.strip())
            if kind == "Real" and not math.isfinite(parsed):
                raise ValueError(value)
        except (ValueError, SspError):
            raise SspError(f"--set {text!r}: {inst}.{pname} must be a finite "
                           f"{kind}") from None
        params[inst][pname] = parsed
    return spec.with_instances(i.with_parameters(**params[i.name]) for i in spec.instances)
