"""The FMI 3.0 face of a native FMU: its variable table, modelDescription and config.h.

``delaycomp build --fmi 3`` compiles the same C model as the FMI 2.0 twin behind the FMI
3.0 layer (``fmus/native/fmi3.c``). The variables are the FMI 2.0 table's, regrouped:

- each vector or matrix the model's manifest lists under ``[fmi3.arrays]`` (``A[i,j]``,
  ``x0[i]``, ...) is one ``Float64`` array, row-major, whose ``<Dimension>``\\ s name
  structural parameters (``[fmi3.structural]``: ``n``, ``m``), and whose value reference
  is its first element's FMI 2.0 value reference, so that every other variable (the
  scalar parameters, the inputs and outputs) keeps its FMI 2.0 value reference;
- the structural parameters are ``UInt64``, ``causality="structuralParameter"``,
  ``variability="fixed"``, with value references after the table's, and after them the
  independent variable ``time`` (FMI 3.0 requires one);
- ``Real`` is ``Float64``, ``Integer`` ``Int32``; Strings carry their start value as a
  ``<Start>`` element.

The inputs and outputs stay scalar (``y1 .. yn``, ``u1 .. um``): the loop is wired port
by port as with FMI 2.0 FMUs (SSP 1.0 connectors are scalar), and an FMI 3.0 controller
connects to another tool's FMI 2.0 plant unchanged.

A clocked build (``clock``: the manifest's ``[fmi3.clock]``, the controller's) adds an
input ``Clock``, time-based and periodic, its interval the parameter it names
(``intervalVariability="fixed"``), and clocks every input and output with it
(``clocks``; the inputs ``variability="discrete"``); the FMU then has event mode
(``fmus/native/fmi3.c``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from xml.etree.ElementTree import Element, SubElement, tostring

from delaycomp.errors import DelaycompError
from delaycomp.names import array_element

__all__ = ["Fmi3Table", "Fmi3TableError", "Fmi3Variable", "build_description",
           "config_block", "fmi3_table", "model_description"]

_TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}
_CODE = {"Float64": "r", "Int32": "i", "Boolean": "b", "String": "s", "UInt64": "n",
         "Clock": "k"}
_CAUSALITY = {"parameter": "p", "input": "i", "output": "o", "structuralParameter": "s",
              "independent": "t"}


class Fmi3TableError(DelaycompError, ValueError):
    """The FMI 2.0 table and the manifest's ``[fmi3]`` section do not fit together."""


@dataclass
class Fmi3Variable:
    """One variable of the FMI 3.0 table."""

    name: str
    vr: int  #: FMI 3.0 value reference (an array's: its first element's slot)
    first: int  #: first slot of the shared table (FMI 2.0 value reference); -1: structural
    count: int  #: elements (1 for a scalar)
    type: str  #: Float64, Int32, Boolean, String, UInt64
    causality: str
    variability: str
    description: str | None = None
    starts: list[str] = field(default_factory=list)  #: start values, row-major
    dims: tuple[str, ...] = ()  #: the structural parameters of its dimensions
    attrib: dict[str, str] = field(default_factory=dict)  #: initial, unit, declaredType, ...
    value: int = 0  #: a structural parameter's value
    clocks: int | None = None  #: the value reference of the clock of a clocked variable


@dataclass
class Fmi3Table:
    """The FMI 3.0 variables of one FMU, in modelDescription order, over the ``nslots``
    scalars of its FMI 2.0 table (the C code's slots)."""

    variables: list[Fmi3Variable]
    nslots: int  #: variables of the FMI 2.0 table (slots)
    #: a clocked build: the clock's variable and the slot of the parameter its interval is
    clock: Fmi3Variable | None = None
    interval_slot: int = -1

    def by_name(self) -> dict[str, Fmi3Variable]:
        """name -> variable."""
        return {v.name: v for v in self.variables}


def fmi3_table(root: Element, structural: dict[str, str], arrays: dict[str, list[str]],
               clock: dict[str, str] | None = None, optional: tuple[str, ...] = ()
               ) -> Fmi3Table:
    """The FMI 3.0 table of the FMI 2.0 table tree ``root`` (the Python twin's
    modelDescription), grouping the manifest's ``arrays`` (name -> its dimensions, each a
    key of ``structural``: name -> description); with ``clock`` (``name``, ``interval``:
    the parameter that gives it, ``description``), a clocked build's. An array of
    ``optional`` without elements in this build (the channel's trace of length 0) is left
    out, and the structural parameters that size only such arrays with it.

    Raises
    ------
    Fmi3TableError
        An array of the manifest is not in the table, or not a full row-major block of
        consecutive value references, or a structural parameter has two extents.
    """
    variables = root.find("ModelVariables")
    assert variables is not None
    scalars = list(variables)
    names = {sv.get("name") for sv in scalars}
    blocks: dict[str, list[tuple[tuple[int, ...], Element]]] = {a: [] for a in arrays}
    for sv in scalars:
        parsed = array_element(sv.get("name", ""))
        if parsed and parsed[0] in blocks:
            blocks[parsed[0]].append((parsed[1], sv))
    empty = {a for a in optional if a in blocks and not blocks[a]}
    dropped = {d for a in empty for d in arrays[a]}
    arrays = {a: dims for a, dims in arrays.items() if a not in empty}
    sizing = {d for dims in arrays.values() for d in dims}
    structural = {d: text for d, text in structural.items()
                  if d in sizing or d not in dropped}
    extents: dict[str, int] = {}
    out: list[Fmi3Variable] = []
    grouped: dict[str, Fmi3Variable] = {}
    for name, dims in arrays.items():
        elements = blocks[name]
        if not elements:
            raise Fmi3TableError(f"array {name!r} of the manifest is no variable of "
                                 f"{root.get('modelName')}")
        shape = tuple(max(ix[d] for ix, _ in elements) for d in range(len(dims)))
        if any(len(ix) != len(dims) for ix, _ in elements):
            raise Fmi3TableError(f"array {name!r}: its elements have {len(elements[0][0])} "
                                 f"indices, the manifest gives {len(dims)} dimensions")
        for dim, extent in zip(dims, shape):
            if dim not in structural:
                raise Fmi3TableError(f"array {name!r}: dimension {dim!r} is no structural "
                                     "parameter of the manifest")
            if extents.setdefault(dim, extent) != extent:
                raise Fmi3TableError(f"structural parameter {dim!r} is {extents[dim]} and "
                                     f"{extent} (array {name!r})")
        order = sorted(elements, key=lambda e: e[0])
        vrs = [int(sv.get("valueReference", "-1")) for _, sv in order]
        count = 1
        for extent in shape:
            count *= extent
        if len(order) != count or vrs != list(range(vrs[0], vrs[0] + count)):
            raise Fmi3TableError(f"array {name!r}: its elements are not a full row-major "
                                 "block of consecutive value references")
        first = order[0][1]
        typed = next(iter(first))
        description = _joined([sv.get("description") or "" for _, sv in order])
        grouped[name] = Fmi3Variable(
            name=name, vr=vrs[0], first=vrs[0], count=count, type=_TYPES[typed.tag],
            causality=first.get("causality", "local"),
            variability=first.get("variability", "continuous"), description=description,
            starts=[next(iter(sv)).get("start") or "0" for _, sv in order], dims=tuple(dims),
            attrib=_attributes(first, typed))
    unused = set(structural) - set(extents)
    if unused:
        raise Fmi3TableError(f"structural parameter {sorted(unused)[0]!r} sizes no array")
    taken = {n for n in names if n is not None} | set(arrays)
    rename: dict[str, str] = {}
    for dim in structural:  # a model's own parameter may be called n: keep it, rename ours
        unique = dim
        while unique in taken:
            unique += "_dim"
        rename[dim] = unique
        taken.add(unique)
    nslots = len(scalars)
    for k, (dim, description) in enumerate(structural.items()):
        out.append(Fmi3Variable(
            name=rename[dim], vr=nslots + k, first=-1, count=1, type="UInt64",
            causality="structuralParameter", variability="fixed", description=description,
            starts=[str(extents[dim])], value=extents[dim]))
    time = "time"
    while time in taken:
        time += "_"
    out.append(Fmi3Variable(name=time, vr=nslots + len(structural), first=-1, count=1,
                            type="Float64", causality="independent",
                            variability="continuous", description="simulation time"))
    clock_var, interval_slot = None, -1
    if clock is not None:
        by_name = {sv.get("name"): sv for sv in scalars}
        interval = by_name.get(clock["interval"])
        if interval is None or next(iter(interval)).tag != "Real":
            raise Fmi3TableError(f"the clock's interval {clock['interval']!r} is no Real "
                                 f"parameter of {root.get('modelName')}")
        if clock["name"] in taken or clock["name"] == time:
            raise Fmi3TableError(f"the clock's name {clock['name']!r} is taken")
        interval_slot = int(interval.get("valueReference", "-1"))
        clock_var = Fmi3Variable(
            name=clock["name"], vr=nslots + len(structural) + 1, first=-1, count=1,
            type="Clock", causality="input", variability="discrete",
            description=clock.get("description"),
            attrib={"intervalVariability": "fixed"})
        out.append(clock_var)
    for var in grouped.values():
        var.dims = tuple(rename[d] for d in var.dims)
    done: set[str] = set()
    for sv in scalars:
        parsed = array_element(sv.get("name", ""))
        if parsed and parsed[0] in grouped:
            if parsed[0] not in done:
                out.append(grouped[parsed[0]])
                done.add(parsed[0])
            continue
        typed = next(iter(sv))
        vr = int(sv.get("valueReference", "-1"))
        start = typed.get("start")
        out.append(Fmi3Variable(
            name=sv.get("name", ""), vr=vr, first=vr, count=1, type=_TYPES[typed.tag],
            causality=sv.get("causality", "local"),
            variability=sv.get("variability", "continuous"),
            description=sv.get("description"), starts=[] if start is None else [start],
            attrib=_attributes(sv, typed)))
    if clock_var is not None:  # every input and output ticks with the clock
        for var in out:
            if var.causality in ("input", "output") and var is not clock_var:
                var.clocks = clock_var.vr
                var.variability = "discrete"
    return Fmi3Table(out, nslots, clock_var, interval_slot)


def _joined(descriptions: list[str]) -> str | None:
    """One description for an array's elements: theirs if they agree, else their common
    words and each element's rest (``initial state x1(t0), x2(t0)``)."""
    if len(set(descriptions)) <= 1:
        return descriptions[0] or None
    words = [d.split(" ") for d in descriptions]
    common = 0
    while all(len(w) > common + 1 and w[common] == words[0][common] for w in words):
        common += 1
    return " ".join([*words[0][:common], ", ".join(" ".join(w[common:]) for w in words)])


def _attributes(sv: Element, typed: Element) -> dict[str, str]:
    keep = {k: v for k, v in sv.attrib.items() if k == "initial"}
    keep.update({k: v for k, v in typed.attrib.items()
                 if k in ("unit", "declaredType", "quantity", "displayUnit", "min", "max",
                          "nominal")})
    return keep


def config_block(table: Fmi3Table) -> list[str]:
    """The lines of config.h that give ``fmi3.c`` its variables (``VAR3``) and the index
    of each FMI 3.0 value reference (``VAR3_INDEX``: -1 where none starts)."""
    nvr3 = table.nslots + sum(v.first < 0 for v in table.variables)
    index = [-1] * nvr3
    for k, var in enumerate(table.variables):
        index[var.vr] = k
    lines = [f"#define NV3 {len(table.variables)}", f"#define NVR3 {nvr3}"]
    if table.clock is not None:
        lines += ["#define CLOCKED 1", f"#define CLOCK_NAME \"{table.clock.name}\"",
                  f"#define CLOCK_VR {table.clock.vr}",
                  f"#define CLOCK_INTERVAL_SLOT {table.interval_slot}"]
    lines += ["static const Var3 VAR3[NV3] = {"]
    for var in table.variables:
        lines.append(f"    {{{max(var.first, 0)}u, {var.count}u, '{_CODE[var.type]}', "
                     f"'{_CAUSALITY[var.causality]}', \"{var.name}\", {var.value}ull}},")
    lines += ["};", "static const int VAR3_INDEX[NVR3] = {"]
    lines += [f"    {i}," for i in index]
    lines += ["};"]
    return lines


def model_description(root: Element, table: Fmi3Table, ident: str, token: str,
                      generation_tool: str) -> bytes:
    """The FMI 3.0 modelDescription.xml of the table, its header taken from the FMI 2.0
    tree ``root`` (co-simulation only, no event mode, FMU state and its serialization)."""
    md = Element("fmiModelDescription", attrib={"fmiVersion": "3.0"})
    for key in ("modelName", "description", "author", "version", "copyright", "license"):
        if root.get(key) is not None:
            md.set(key, root.get(key, ""))
    md.set("instantiationToken", token)
    md.set("generationTool", generation_tool)
    md.set("variableNamingConvention", "structured")
    cs2 = root.find("CoSimulation")
    assert cs2 is not None
    SubElement(md, "CoSimulation", attrib={
        "modelIdentifier": ident, "needsExecutionTool": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true",
        "canHandleVariableCommunicationStepSize":
            cs2.get("canHandleVariableCommunicationStepSize", "false"),
        "hasEventMode": "false" if table.clock is None else "true"})
    units = root.find("UnitDefinitions")
    if units is not None:
        md.append(units)
    types = root.find("TypeDefinitions")
    if types is not None:
        out_types = SubElement(md, "TypeDefinitions")
        for simple in types:
            typed = next(iter(simple))
            SubElement(out_types, f"{_TYPES[typed.tag]}Type",
                       attrib={"name": simple.get("name", ""), **typed.attrib})
    categories = root.find("LogCategories")
    if categories is not None:
        cats = SubElement(md, "LogCategories")
        for cat in categories:
            SubElement(cats, "Category", attrib={
                k: v.replace("fmi2", "fmi3") for k, v in cat.attrib.items()})
    experiment = root.find("DefaultExperiment")
    if experiment is not None:
        md.append(experiment)
    variables = SubElement(md, "ModelVariables")
    for var in table.variables:
        attrib = {"name": var.name, "valueReference": str(var.vr)}
        if var.description:
            attrib["description"] = var.description
        attrib["causality"] = var.causality
        attrib["variability"] = var.variability
        attrib.update(var.attrib)
        if var.clocks is not None:
            attrib["clocks"] = str(var.clocks)
        if var.starts and var.type != "String":
            attrib["start"] = " ".join(var.starts)
        element = SubElement(variables, var.type, attrib=attrib)
        if var.type == "String":
            for start in var.starts:
                SubElement(element, "Start", attrib={"value": start})
        by_name = table.by_name()
        for dim in var.dims:
            SubElement(element, "Dimension", attrib={"valueReference": str(by_name[dim].vr)})
    structure = SubElement(md, "ModelStructure")
    scalars = list(root.find("ModelVariables") or [])
    slot_owner = {}
    for var in table.variables:
        for e in range(var.count if var.first >= 0 else 0):
            slot_owner[var.first + e] = var.vr
    ms2 = root.find("ModelStructure")

    def vr_of(index: str) -> int:  # an FMI 2.0 index (1-based) -> its FMI 3.0 variable
        return slot_owner[int(scalars[int(index) - 1].get("valueReference", "-1"))]

    clocked = {v.vr for v in table.variables if v.clocks is not None}
    for kind, tag in (("Outputs", "Output"), ("InitialUnknowns", "InitialUnknown")):
        block = ms2.find(kind) if ms2 is not None else None
        for unknown in block if block is not None else ():
            vr = vr_of(unknown.get("index", "0"))
            if tag == "InitialUnknown" and vr in clocked:
                continue  # a clocked output has its value from the first tick
            attrib = {"valueReference": str(vr)}
            deps = unknown.get("dependencies")
            if deps is not None:
                attrib["dependencies"] = " ".join(
                    dict.fromkeys(str(vr_of(i)) for i in deps.split()))
            SubElement(structure, tag, attrib=attrib)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(md, encoding="utf-8")


def build_description(ident: str, sources: list[str]) -> bytes:
    """``sources/buildDescription.xml`` (FMI 3.0, 2.5.1.2): the C files to compile, with
    ``sources/`` on the include path."""
    root = Element("fmiBuildDescription", attrib={"fmiVersion": "3.0"})
    config = SubElement(root, "BuildConfiguration", attrib={"modelIdentifier": ident})
    files = SubElement(config, "SourceFileSet", attrib={"language": "C99"})
    for name in sources:
        SubElement(files, "SourceFile", attrib={"name": name})
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")
