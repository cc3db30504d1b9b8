"""SSP 1.0 description of a closed loop: ``SystemStructure.ssd``, ``.ssv`` files, ``.ssp``.

The SSD and its parameter sets are written from the same :class:`~delaycomp.system.Loop`
that the master runs, so the two cannot drift apart, and are read back into one.
This module only does XML; there is no maths here.

Layout of a system (a folder, or the zip archive ``<name>.ssp``)::

    SystemStructure.ssd          components, connectors, connections, master settings
    resources/<instance>.ssv     one parameter set per component (SSV 1.0)
    resources/<Model>.fmu        the FMUs (in the archive only)

The archive is written so that every SSP tool we know reads it as it is (our master,
libcosim, Ecos, OMSimulator's Python API and its command line):

- model and system are named by an identifier (:func:`ssd_identifier`: ``example_3_6``; the
  archive file keeps the loop's name, ``example-3.6.ssp``);
- the master settings go into three vendor annotations:

  - ``org.openmodelica`` on the root system: ``<oms:FixedStepMaster stepSize="h">``, which
    OMSimulator needs (its command line refuses a system without it);
  - ``com.opensimulationplatform`` in the default experiment:
    ``<osp:FixedStepAlgorithm baseStepSize="h">``, which libcosim reads (only when
    ``xmlns:osp`` is declared on the root, as here);
  - ``org.delaycomp.master`` in the default experiment: ``<dc:Master T= N= h= name=>``
    with the recorded signals and one ``<dc:Component element= role= kind= config=
    choices=>`` per component, what :func:`delaycomp.simulate.source_fmu` needs to rebuild
    its FMU (namespace :data:`DC_NS`). Components carry no annotation: OMSimulator's schema
    check refuses ``ssd:Annotations`` there. (Archives written before kept ``<dc:Fmu>`` in
    each component; they are still read.)

Parameters are bound per component (``<ssd:ParameterBinding source="resources/plant.ssv">``)
and named by the FMU variable, as libcosim and Ecos expect. Every parameter set of a
system has the same name (:data:`DEFAULT_SET` unless told otherwise): Ecos applies the set
named in its ``init()``. The sets hold only Real, Integer and Boolean values, which every
importer applies: a String parameter with a fixed set of choices (the controller's
``mode``, ...) is written as its FMU's Integer twin ``<name>_index`` (1 = the first choice,
...; see :func:`foreign_parameters`) and read back as the String.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import tempfile
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

from .errors import ParameterError, SspError
from .system import ROLES, BuiltinFmu, Connection, FmuFile, Instance, Loop, ModelFmu, Port, Timing
from .tmpfiles import zip_folder

SSD_NS = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP_NS = "http://opensimulationplatform.com/SSP/OSPAnnotations"
#: OMSimulator's namespace (the one its own writer declares)
OMS_NS = "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"
#: the project's own namespace for the master annotation
DC_NS = "urn:delaycomp:ssp:1"
NSMAP = {"ssd": SSD_NS, "ssc": SSC_NS, "ssv": SSV_NS, "osp": OSP_NS, "oms": OMS_NS,
         "dc": DC_NS}

#: annotation types
DC_ANNOTATION = "org.delaycomp.master"
OSP_ANNOTATION = "com.opensimulationplatform"
OMS_ANNOTATION = "org.openmodelica"
#: suffix of a String parameter's Integer twin (:mod:`delaycomp.fmuslave`, item 7)
INDEX_SUFFIX = "_index"

SSD_NAME = "SystemStructure.ssd"
RESOURCES = "resources"
DEFAULT_SET = "default"
FMU_MIME = "application/x-fmu-sharedlibrary"

#: FMU kinds whose build config names a model file (``config["model"]``)
_MODEL_PREFIX = "builtin:"


def tag(name: str) -> str:
    """``"ssd:System"`` -> ``"{http://...SystemStructureDescription}System"``."""
    prefix, _, local = name.partition(":")
    return f"{{{NSMAP[prefix]}}}{local}"


# -- values --------------------------------------------------------------------------------

def _ssv_type(value) -> str:
    if isinstance(value, bool):
        return "Boolean"
    if isinstance(value, int):
        return "Integer"
    if isinstance(value, float):
        return "Real"
    if isinstance(value, str):
        return "String"
    raise TypeError(f"parameter value {value!r} has no SSV type")


def _format(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"parameter value {value!r} is not finite")
        return repr(value)  # shortest repr: reads back bit-identically
    return str(value)


def _parse(kind: str, text: str):
    if kind == "Real":
        return float(text)
    if kind == "Integer":
        return int(text)
    if kind == "Boolean":
        if text not in ("true", "false", "1", "0"):
            raise SspError(f"Boolean value {text!r} is not true/false")
        return text in ("true", "1")
    return text


# -- names and parameters a foreign importer can apply -------------------------------------

def ssd_identifier(name: str) -> str:
    """``name`` as an identifier for the SSD's model and system (OMSimulator's command line
    refuses any other): each character outside ``[A-Za-z0-9_]`` becomes ``_``, and a name
    that starts with a digit gets a leading ``_``.

    Examples
    --------
    >>> ssd_identifier("example-3.6")
    'example_3_6'
    >>> ssd_identifier("2-loops")
    '_2_loops'
    """
    ident = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    return f"_{ident}" if ident[0].isdigit() else ident


def parameter_choices(key: tuple[str, dict] | None) -> dict[str, tuple[str, ...]]:
    """The String parameters with a fixed set of choices of the FMU built from ``key``
    (``source.build_key()``: kind and config; None for a user's FMU file, whose Strings
    are left as they are), in the order of their Integer twins (index 1 = the first
    choice)."""
    if key is None:
        return {}
    kind, config = key
    if kind == "controller":
        from .lti import MODES

        return {"mode": tuple(MODES)}
    if kind in ("model_plant", "model_controller") and "model" in config:
        from .model import CONTROLS, load_model
        from .nlcontrol import PREDICTORS

        choices = dict(load_model(config["model"]).choices)
        if kind == "model_controller":
            choices = {"mode": CONTROLS, "predictor": PREDICTORS, **choices}
        return {k: tuple(v) for k, v in choices.items()}
    return {}


def foreign_parameters(params: dict, choices: dict[str, tuple[str, ...]]) -> dict:
    """``params`` as an importer without String parameters can apply them: each String
    with ``choices`` becomes its Integer twin ``<name>_index`` (1-based), in its place.
    A String without choices, or with a value outside them, stays a String (the FMU then
    reports the bad value)."""
    out = {}
    for name, value in params.items():
        if isinstance(value, str) and value in choices.get(name, ()):
            out[f"{name}{INDEX_SUFFIX}"] = choices[name].index(value) + 1
        else:
            out[name] = value
    return out


def native_parameters(params: dict, choices: dict[str, tuple[str, ...]], where: str) -> dict:
    """The inverse of :func:`foreign_parameters`: each Integer twin back into its String
    (an index 0 leaves the String to its FMU default, so the String is omitted)."""
    out = {}
    for name, value in params.items():
        base = name[:-len(INDEX_SUFFIX)] if name.endswith(INDEX_SUFFIX) else None
        if base is None or base not in choices or isinstance(value, bool) \
                or not isinstance(value, int):
            out[name] = value
            continue
        if not 0 <= value <= len(choices[base]):
            raise SspError(f"{where}: {name} = {value} is not allowed: must be 0 .. "
                           f"{len(choices[base])} ({', '.join(choices[base])})")
        if value:
            out[base] = choices[base][value - 1]
    return out


# -- model references ----------------------------------------------------------------------

def _config_out(config: dict) -> dict:
    """The build config with a model file named without a machine path."""
    out = dict(config)
    if "model" in out:
        from .models import HERE

        path = Path(out["model"]).resolve()
        out["model"] = (f"{_MODEL_PREFIX}{path.stem}" if path.parent == HERE
                        else path.name)
    return out


def _config_in(config: dict) -> dict:
    out = dict(config)
    model = out.get("model")
    if isinstance(model, str) and model.startswith(_MODEL_PREFIX):
        from .models import path

        out["model"] = str(path(model[len(_MODEL_PREFIX):]))
    return out


# -- writing -------------------------------------------------------------------------------

@dataclass(frozen=True)
class SystemInfo:
    """What an SSD says beyond the loop: its name, description, stop time, set name."""

    name: str
    description: str = ""
    stop_time: float | None = None
    parameter_set: str = DEFAULT_SET


def ssv_document(name: str, parameters: dict) -> etree._ElementTree:
    """An SSV 1.0 parameter set ``name`` with one typed value per parameter."""
    root = etree.Element(tag("ssv:ParameterSet"), nsmap={"ssv": SSV_NS},
                         attrib={"version": "1.0", "name": name})
    params = etree.SubElement(root, tag("ssv:Parameters"))
    for pname, value in parameters.items():
        p = etree.SubElement(params, tag("ssv:Parameter"), name=pname)
        etree.SubElement(p, tag(f"ssv:{_ssv_type(value)}"), value=_format(value))
    return etree.ElementTree(root)


def ssd_document(spec: Loop, info: SystemInfo,
                 fmu_files: dict[str, str]) -> etree._ElementTree:
    """The SSD of ``spec``; ``fmu_files`` maps each instance to its FMU file name."""
    connectors: dict[str, list[tuple[str, str]]] = {name: [] for name in spec.names}
    for con in spec.connections:
        for port, kind in ((con.src, "output"), (con.dst, "input")):
            if (port.variable, kind) not in connectors[port.instance]:
                connectors[port.instance].append((port.variable, kind))
    for port in spec.recorded:
        have = connectors[port.instance]
        if (port.variable, "output") not in have and (port.variable, "input") not in have:
            have.append((port.variable, "output"))

    ident = ssd_identifier(info.name)
    root = etree.Element(tag("ssd:SystemStructureDescription"), nsmap=NSMAP,
                         attrib={"version": "1.0", "name": ident})
    system = etree.SubElement(root, tag("ssd:System"), name=ident)
    if info.description:
        system.set("description", info.description)
    elements = etree.SubElement(system, tag("ssd:Elements"))
    choices = {i.name: parameter_choices(i.source.build_key()) for i in spec.instances}
    for inst in spec.instances:
        comp = etree.SubElement(elements, tag("ssd:Component"), name=inst.name, type=FMU_MIME,
                                source=f"{RESOURCES}/{fmu_files[inst.name]}")
        conns = etree.SubElement(comp, tag("ssd:Connectors"))
        for var, ckind in connectors[inst.name]:
            c = etree.SubElement(conns, tag("ssd:Connector"), name=var, kind=ckind)
            etree.SubElement(c, tag("ssc:Real"))
        for pname, value in foreign_parameters(inst.parameters, choices[inst.name]).items():
            c = etree.SubElement(conns, tag("ssd:Connector"), name=pname, kind="parameter")
            etree.SubElement(c, tag(f"ssc:{_ssv_type(value)}"))
        bindings = etree.SubElement(comp, tag("ssd:ParameterBindings"))
        etree.SubElement(bindings, tag("ssd:ParameterBinding"),
                         source=f"{RESOURCES}/{inst.name}.ssv")
    connections = etree.SubElement(system, tag("ssd:Connections"))
    for con in spec.connections:
        etree.SubElement(connections, tag("ssd:Connection"), startElement=con.src.instance,
                         startConnector=con.src.variable, endElement=con.dst.instance,
                         endConnector=con.dst.variable)

    h = spec.T / spec.N
    _oms_annotation(system, h)
    exp = etree.SubElement(root, tag("ssd:DefaultExperiment"), startTime="0.0")
    if info.stop_time is not None:
        exp.set("stopTime", _format(float(info.stop_time)))
    anns = etree.SubElement(exp, tag("ssd:Annotations"))
    osp = etree.SubElement(anns, tag("ssc:Annotation"), type=OSP_ANNOTATION)
    alg = etree.SubElement(osp, tag("osp:Algorithm"))
    etree.SubElement(alg, tag("osp:FixedStepAlgorithm"), baseStepSize=_format(h))
    dc = etree.SubElement(anns, tag("ssc:Annotation"), type=DC_ANNOTATION)
    master = etree.SubElement(dc, tag("dc:Master"), T=_format(float(spec.T)), N=str(spec.N),
                              h=_format(h), parameterSet=info.parameter_set,
                              name=info.name)
    for port in spec.recorded:
        etree.SubElement(master, tag("dc:Record"), element=port.instance,
                         connector=port.variable)
    for inst in spec.instances:
        _component_annotation(master, inst, choices[inst.name])
    return etree.ElementTree(root)


def _component_annotation(master: etree._Element, inst: Instance,
                          choices: dict[str, tuple[str, ...]]) -> None:
    """``<dc:Component element= role= kind= config= choices=>``: which FMU an instance is
    (no kind and config for a user's FMU file) and its String choices."""
    comp = etree.SubElement(master, tag("dc:Component"), element=inst.name, role=inst.role)
    key = inst.source.build_key()
    if key is not None:
        comp.set("kind", key[0])
        comp.set("config", json.dumps(_config_out(key[1]), sort_keys=True))
    comp.set("choices", json.dumps(choices, sort_keys=True))


def _oms_annotation(system: etree._Element, h: float) -> None:
    """OMSimulator's master settings on the root system (its command line needs them)."""
    anns = etree.SubElement(system, tag("ssd:Annotations"))
    ann = etree.SubElement(anns, tag("ssc:Annotation"), type=OMS_ANNOTATION)
    info = etree.SubElement(etree.SubElement(ann, tag("oms:Annotations")),
                            tag("oms:SimulationInformation"))
    etree.SubElement(info, tag("oms:FixedStepMaster"), description="oms-ma",
                     stepSize=_format(h))


def _fmu_file_names(spec: Loop) -> dict[str, str]:
    from .simulate import fmu_file_name

    return {i.name: (Path(i.source.path).name if isinstance(i.source, FmuFile)
                     else fmu_file_name(*i.source.build_key())) for i in spec.instances}


def _write(tree: etree._ElementTree, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(etree.tostring(tree, xml_declaration=True, encoding="UTF-8",
                                    pretty_print=True))


def write_system(spec: Loop, info: SystemInfo, folder: str | Path) -> Path:
    """Write ``SystemStructure.ssd`` and ``resources/<instance>.ssv`` into ``folder``."""
    folder = Path(folder)
    _write(ssd_document(spec, info, _fmu_file_names(spec)), folder / SSD_NAME)
    for inst in spec.instances:
        ssv = foreign_parameters(inst.parameters, parameter_choices(inst.source.build_key()))
        _write(ssv_document(info.parameter_set, ssv), folder / RESOURCES / f"{inst.name}.ssv")
    return folder / SSD_NAME


def pack(spec: Loop, info: SystemInfo, out: str | Path,
         fmu_dir: Path | None = None, fmus: dict[str, Path] | None = None) -> Path:
    """Write the archive ``out`` (``.ssp``): the SSD, its SSVs and the FMUs.

    The FMUs are taken from ``fmus`` (instance -> path) where given, else from
    :func:`delaycomp.simulate.source_fmu` (built into ``fmu_dir`` or the cache if missing).
    """
    from .simulate import source_fmu

    out = Path(out)
    names = _fmu_file_names(spec)
    with tempfile.TemporaryDirectory(prefix="delaycomp-ssp-") as tmp:
        folder = Path(tmp)
        write_system(spec, info, folder)
        for inst in spec.instances:
            src = (fmus or {}).get(inst.name) or source_fmu(inst.source, fmu_dir)
            target = folder / RESOURCES / names[inst.name]
            if not target.exists():
                shutil.copyfile(src, target)
        out.parent.mkdir(parents=True, exist_ok=True)
        zip_folder(folder, out)
    return out


# -- reading -------------------------------------------------------------------------------

@dataclass(frozen=True)
class System:
    """An SSD read back: the loop, what else it says, and each instance's FMU file."""

    spec: Loop
    info: SystemInfo
    #: instance -> the component's ``source`` (relative to the SSD)
    sources: dict[str, str]


def _parse_xml(path: Path) -> etree._Element:
    try:
        return etree.parse(str(path)).getroot()
    except (OSError, etree.XMLSyntaxError) as exc:
        raise SspError(f"{path.name}: not readable XML: {exc}") from None


def _attr(el: etree._Element, name: str, where: str) -> str:
    value = el.get(name)
    if value is None:
        raise SspError(f"{where}: missing attribute {name!r}")
    return value


def read_ssv(path: str | Path) -> tuple[str, dict]:
    """Name and parameters (typed values) of the SSV parameter set at ``path``."""
    path = Path(path)
    root = _parse_xml(path)
    if root.tag != tag("ssv:ParameterSet"):
        raise SspError(f"{path.name}: not an SSV 1.0 parameter set (root {root.tag})")
    params = {}
    for p in root.iterfind("ssv:Parameters/ssv:Parameter", NSMAP):
        name = _attr(p, "name", path.name)
        value = next(iter(p), None)
        if value is None or not isinstance(value.tag, str):
            raise SspError(f"{path.name}: parameter {name!r} has no value")
        kind = etree.QName(value).localname
        if kind not in ("Real", "Integer", "Boolean", "String"):
            raise SspError(f"{path.name}: parameter {name!r} has unsupported type {kind}")
        try:
            params[name] = _parse(kind, _attr(value, "value", f"{path.name}: {name}"))
        except ValueError:
            raise SspError(f"{path.name}: parameter {name!r}: bad {kind} value "
                           f"{value.get('value')!r}") from None
    return _attr(root, "name", path.name), params


#: largest dc:Master N read from an SSD (base steps per sampling period)
MAX_N = 10**6
#: what an archive may unpack to: members and bytes (the sizes the zip declares, which
#: zipfile enforces while extracting); our archives hold a few FMUs of about 0.5 MB
MAX_MEMBERS = 1000
MAX_UNPACKED = 512 * 2**20


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
                 connections: list[Connection]) -> dict[str, str]:
    """Fill unknown roles by walking the component cycle from the plant (see Foreign)."""
    unknown = [n for n in names if roles[n] is None]
    if not unknown:
        return dict(roles)  # type: ignore[arg-type]
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
    """Read an SSD written by :func:`write_system` (and its SSVs) back into a loop.

    With ``foreign`` an SSD without delaycomp's annotations is read too (an SSP 1.0 of
    another tool): its master settings and roles come from ``foreign`` (:class:`Foreign`),
    its components are FMU files as they are, and the recorded signals are the plant's and
    the controller's connected outputs."""
    ssd_path = Path(ssd_path)
    root = _parse_xml(ssd_path)
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
    given_roles = dict(foreign.roles) if foreign is not None else {}
    for cname, role in given_roles.items():
        if role not in ROLES:
            raise SspError(f"--role {cname}={role}: role {role!r} is not allowed: allowed "
                           f"are {', '.join(ROLES)}")
    described = ({c.get("element"): c for c in master.iterfind("dc:Component", NSMAP)}
                 if master is not None else {})
    roles: dict[str, str | None] = {}
    instances, sources, set_names = [], {}, set()
    for comp in system.iterfind("ssd:Elements/ssd:Component", NSMAP):
        name = _attr(comp, "name", where)
        sources[name] = _inside(ssd_path, _attr(comp, "source", f"{where}: component {name}"),
                                f"{where}: component {name}")
        fmu = described.get(name)
        if fmu is None:  # an archive of an earlier layout: the description in the component
            fmu = comp.find(f"ssd:Annotations/ssc:Annotation[@type='{DC_ANNOTATION}']/dc:Fmu",
                            NSMAP)
        if fmu is None and foreign is None:
            raise SspError(f"{where}: component {name} has no dc:Component (nor dc:Fmu) "
                           "annotation")
        choices: dict = {}
        if fmu is None:
            role = given_roles.get(name) or (name if name in ROLES else None)
        else:
            try:
                choices = {k: tuple(v)
                           for k, v in json.loads(fmu.get("choices", "{}")).items()}
            except (json.JSONDecodeError, AttributeError, TypeError):
                raise SspError(f"{where}: component {name}: choices is not a JSON object of "
                               "lists") from None
            # archives before roles named instances by role
            role = given_roles.get(name) or fmu.get("role") or name
            if role not in ROLES:
                raise SspError(f"{where}: component {name} has role {role!r}: allowed are "
                               f"{', '.join(ROLES)}")
        roles[name] = role
        kind = fmu.get("kind") if fmu is not None else None
        if kind is None:
            source = FmuFile(ssd_path.parent / sources[name])
        else:
            try:
                config = _config_in(json.loads(_attr(fmu, "config", f"{where}: {name}")))
            except json.JSONDecodeError:
                raise SspError(f"{where}: component {name}: dc:Fmu config is not JSON"
                               ) from None
            source = (ModelFmu(kind, Path(config["model"])) if "model" in config
                      else BuiltinFmu(kind, config))
        params: dict = {}
        for binding in comp.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NSMAP):
            bsource = _inside(ssd_path, _attr(binding, "source", f"{where}: component {name}"),
                              f"{where}: component {name}")
            set_name, values = read_ssv(ssd_path.parent / bsource)
            set_names.add(set_name)
            params.update(values)
        params = native_parameters(params, choices, f"{where}: component {name}")
        instances.append((name, source, params))
    for name in given_roles:
        if name not in roles:
            raise SspError(f"--role {name}=...: {where} has no component {name!r}: its "
                           f"components are {', '.join(roles)}")
    connections = []
    for c in system.iterfind("ssd:Connections/ssd:Connection", NSMAP):
        ends = [_attr(c, a, f"{where}: connection") for a in
                ("startElement", "startConnector", "endElement", "endConnector")]
        connections.append(Connection(Port(ends[0], ends[1]), Port(ends[2], ends[3])))
    found = _infer_roles(where, list(roles), roles, connections)
    instances = [Instance(name, found[name], source, params)
                 for name, source, params in instances]
    if master is not None:
        recorded = [Port(_attr(r, "element", where), _attr(r, "connector", where))
                    for r in master.iterfind("dc:Record", NSMAP)]
    else:
        by_role = {role: name for name, role in found.items()}
        recorded = list(dict.fromkeys(
            c.src for role in ("plant", "controller") for c in connections
            if c.src.instance == by_role.get(role)))
    try:
        if foreign is not None and foreign.T is not None and foreign.N is not None:
            T, N = float(foreign.T), foreign.N
        else:
            T, N = float(_attr(master, "T", where)), int(_attr(master, "N", where))
    except ValueError:
        raise SspError(f"{where}: dc:Master T and N must be numbers") from None
    if not (math.isfinite(T) and T > 0):
        raise SspError(f"{where}: dc:Master T = {T!r} is not allowed: must be a finite "
                       "number > 0")
    if not 1 <= N <= MAX_N:
        raise SspError(f"{where}: dc:Master N = {N!r} is not allowed: must be an integer "
                       f"from 1 to {MAX_N}")
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
        info = SystemInfo(master.get("name", root.get("name", "")),
                          system.get("description", ""), stop_time,
                          master.get("parameterSet", set_name))
    else:
        info = SystemInfo(root.get("name", ""), system.get("description", ""), stop_time,
                          set_name)
    try:
        loop = Loop(instances, connections, Timing(T, N), recorded, info.name,
                    info.description)
    except ParameterError as exc:
        raise SspError(f"{where}: {exc}") from None
    return System(loop, info, sources)


def _check_member_fmu(path: Path, where: str) -> None:
    """Refuse an FMU inside an archive that is not a zip with a readable
    modelDescription (one line, instead of fmpy's traceback at the first run)."""
    from fmpy import read_model_description

    try:
        with zipfile.ZipFile(path) as zf:
            if "modelDescription.xml" not in zf.namelist():
                raise SspError(f"{where} is not an FMU: it has no modelDescription.xml")
        md = read_model_description(str(path), validate=False)
    except SspError:
        raise
    except zipfile.BadZipFile:
        raise SspError(f"{where} is not an FMU: not a zip archive") from None
    except Exception as exc:  # noqa: BLE001 - any parse failure is a bad file
        raise SspError(f"{where} is not a readable FMU: {type(exc).__name__}: "
                       f"{str(exc).splitlines()[0] if str(exc) else ''}") from None
    if md.coSimulation is None:
        raise SspError(f"{where} is not a co-simulation FMU")


class Archive:
    """An ``.ssp`` archive unpacked into a temporary folder (a context manager)."""

    def __init__(self, path: str | Path, foreign: Foreign | None = None):
        self.path = Path(path)
        self.foreign = foreign
        self._tmp: tempfile.TemporaryDirectory | None = None
        self.folder: Path | None = None
        self.system: System | None = None

    def __enter__(self) -> Archive:
        if not self.path.is_file():
            raise SspError(f"{self.path.name}: no such file")
        self._tmp = tempfile.TemporaryDirectory(prefix="delaycomp-ssp-")
        self.folder = Path(self._tmp.name)
        try:
            with zipfile.ZipFile(self.path) as zf:
                infos = zf.infolist()
                total = sum(i.file_size for i in infos)
                if len(infos) > MAX_MEMBERS or total > MAX_UNPACKED:
                    raise SspError(f"{self.path.name}: unpacks to {len(infos)} files of "
                                   f"{total} bytes: at most {MAX_MEMBERS} files and "
                                   f"{MAX_UNPACKED} bytes are allowed")
                for member in zf.namelist():
                    target = (self.folder / member).resolve()
                    if not target.is_relative_to(self.folder.resolve()):
                        raise SspError(f"{self.path.name}: member {member!r} leaves the archive")
                zf.extractall(self.folder)
        except zipfile.BadZipFile:
            self.close()
            raise SspError(f"{self.path.name}: not an SSP archive (not a zip file)") from None
        except SspError:
            self.close()
            raise
        if not (self.folder / SSD_NAME).is_file():
            self.close()
            raise SspError(f"{self.path.name}: no {SSD_NAME} in the archive")
        try:
            self.system = read_system(self.folder / SSD_NAME, self.foreign)
            for inst, source in self.system.sources.items():
                if not (self.folder / source).is_file():
                    raise SspError(f"{self.path.name}: component {inst}: {source} is missing")
                _check_member_fmu(self.folder / source, f"{self.path.name}: component "
                                  f"{inst}: {source}")
        except SspError:
            self.close()
            raise
        return self

    def fmu(self, instance: str) -> Path:
        return self.folder / self.system.sources[instance]

    def fmus(self) -> dict[str, Path]:
        return {inst: self.fmu(inst) for inst in self.system.sources}

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __exit__(self, *exc) -> None:
        self.close()


# -- validation ----------------------------------------------------------------------------

def _schema(name: str) -> etree.XMLSchema:
    import fmpy

    return etree.XMLSchema(etree.parse(str(Path(fmpy.__file__).parent / "ssp" / "schema"
                                           / name)))


def validate(path: str | Path) -> list[str]:
    """Errors of an SSD or SSV against fmpy's SSP 1.0 XSDs (empty when valid)."""
    path = Path(path)
    root = _parse_xml(path)
    name = {tag("ssd:SystemStructureDescription"): "SystemStructureDescription.xsd",
            tag("ssv:ParameterSet"): "SystemStructureParameterValues.xsd"}.get(root.tag)
    if name is None:
        return [f"{path.name}: neither an SSD nor an SSV (root {root.tag})"]
    schema = _schema(name)
    if schema.validate(root.getroottree()):
        return []
    return [f"{path.name}:{e.line}: {e.message}" for e in schema.error_log]


# -- scenarios -----------------------------------------------------------------------------

def scenario_system(name: str, assignments: list[str] | None = None,
                    parameter_set: str = DEFAULT_SET) -> tuple[Loop, SystemInfo]:
    """The loop and SSD header of scenario ``name`` with ``NAME=VALUE`` assignments."""
    from . import scenarios

    return loop_system(scenarios.get(name).loop(list(assignments or [])), parameter_set)


def loop_system(loop: Loop, parameter_set: str = DEFAULT_SET) -> tuple[Loop, SystemInfo]:
    """A loop and the SSD header it gets (its name, title and stop time)."""
    return loop, SystemInfo(loop.name, loop.title, loop.stop_time, parameter_set)


def write_all(folder: str | Path) -> list[Path]:
    """``folder/<scenario>/`` with the SSD and SSVs of every scenario at its defaults."""
    from .scenarios import SCENARIOS

    return [write_system(*scenario_system(name), Path(folder) / name) for name in SCENARIOS]


def pack_scenarios(out_dir: str | Path, fmu_dir: Path | None = None) -> list[Path]:
    """``out_dir/<scenario>.ssp`` for every scenario at its defaults, and its Jacobi variant
    ``out_dir/<scenario>-jacobi.ssp`` for libcosim and Ecos (:mod:`delaycomp.thirdparty`).

    The FMUs come from ``fmu_dir`` where they are (``delaycomp build`` has just built the
    LTI loop's there) and are otherwise built, two at a time, into the build cache.
    """
    from concurrent.futures import ThreadPoolExecutor

    from .scenarios import SCENARIOS
    from .simulate import fmu_file_name, fmu_path

    systems = [scenario_system(name) for name in SCENARIOS]
    wanted = {}
    for spec, _ in systems:
        for inst in spec.instances:
            kind, config = inst.source.build_key()
            wanted.setdefault(fmu_file_name(kind, config), (kind, config))
    have = {name: Path(fmu_dir) / name for name in wanted
            if fmu_dir is not None and (Path(fmu_dir) / name).is_file()}
    missing = [kc for name, kc in wanted.items() if name not in have]
    with ThreadPoolExecutor(max_workers=2) as pool:  # each build is its own process
        built = list(pool.map(lambda kc: fmu_path(*kc), missing))
    have.update({p.name: p for p in built})
    from .system.jacobi import jacobi_variant

    out = []
    for spec, info in systems:
        fmus = {inst.name: have[fmu_file_name(*inst.source.build_key())]
                for inst in spec.instances}
        out.append(pack(spec, info, Path(out_dir) / f"{info.name}.ssp", fmus=fmus))
        variant = jacobi_variant(spec)
        out.append(pack(variant, jacobi_info(info), Path(out_dir) / f"{info.name}-jacobi.ssp",
                        fmus={i: fmus[i] for i in variant.names}))
    return out


def jacobi_info(info: SystemInfo) -> SystemInfo:
    """The SSD header of a Jacobi variant: the description says what was changed."""
    return SystemInfo(info.name, f"{info.description} (Jacobi variant: measurement delay "
                      "shortened by h, controller samples the previous step)",
                      info.stop_time, info.parameter_set)


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
    :class:`SspError`.
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
        kind = (_ssv_type(params[inst][pname]) if pname in params[inst]
                else _fmu_parameter_type(fmus[inst], pname))
        if kind is None:
            raise SspError(f"--set {text!r}: {inst} has no parameter {pname!r}")
        try:
            parsed = _parse(kind, value.strip().lower() if kind == "Boolean" else value.strip())
            if kind == "Real" and not math.isfinite(parsed):
                raise ValueError(value)
        except (ValueError, SspError):
            raise SspError(f"--set {text!r}: {inst}.{pname} must be a finite "
                           f"{kind}") from None
        params[inst][pname] = parsed
    return spec.with_instances(i.with_parameters(**params[i.name]) for i in spec.instances)
