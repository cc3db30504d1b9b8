"""Native C FMUs: the delay, the LTI plant and the LTI predictor-controller without Python.

``delaycomp build --native --out DIR`` (``build_native``) writes FMI 2.0 co-simulation
FMUs whose binary needs only the C library and libm, twins of the pythonfmu FMUs of
``delaycomp.fmu.build.FMUS``:

1. **Same table.** The modelDescription is the Python FMU's own (the slave class, with the
   same build configuration, writes its variables, value references, start values and
   dependencies), with the co-simulation attributes of a C FMU, a pinned GUID of its own
   and ``<SourceFiles>``. A generated ``config.h`` carries that table into C (value
   references, names, types, causalities, start values written as hexadecimal floats).
2. **Same maths and messages.** ``fmus/native/`` holds one FMI layer that knows no model
   (``fmi2.c``: the FMI 2.0 state machine, getters and setters, FMU state with buffers,
   serialization; ``native.c``: logging and the checks the models share; ``pyrepr.c``:
   numbers as Python's ``repr`` writes them), the linear algebra (``linalg.c``: the matrix
   exponential by scaling and squaring with Pade approximants, and the exact flow of
   ``x' = A x + B u``) and DOP853 (``ode.c``). Each model's C lives beside its Python twin
   in ``fmus/<kind>/`` (``NativeTwin``): ``<name>.c`` (its maths), ``<name>.h`` (its
   data) and ``<name>.toml`` (the shared sources it uses and the variables it addresses).
   A fault returns ``fmi2Error`` with the Python FMU's message logged.
3. **Sources inside.** Each FMU carries its C sources and the FMI headers under
   ``sources/`` (listed in modelDescription), so an importer can compile it for another
   platform, and binaries for five platforms (``delaycomp.fmu.toolchain``: Zig's C
   compiler builds them all on any machine; without it a system compiler builds what it
   can), ``-Wall -Wextra -Werror``.

The C host that runs these FMUs without Python is ``delaycomp.fmu.host``; which native
FMUs a loop runs, and from where, is ``delaycomp.fmu.twins``.

The FMI 2.0 headers are fmpy's copy (``fmpy/c-code``; fmpy is a dependency, so a wheel
install has them) and go into each FMU's ``sources/``.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, cast
from xml.etree.ElementTree import Element, SubElement, tostring

from delaycomp.fmu import toolchain
from delaycomp.fmu.build import (
    CONFIG_NAME,
    DEFAULT_CONFIG,
    FMU_ROOT,
    FMUS,
    LOOP_KINDS,
    check_dimensions,
    model_identifier,
)
from delaycomp.fmu.toolchain import NativeBuildError
from delaycomp.tmpfiles import zip_folder
from delaycomp.version import __version__

if TYPE_CHECKING:
    from delaycomp.fmu.fmi3 import Fmi3Table
    from delaycomp.fmu.translate import Translation

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as the tomli package
    import tomli as tomllib

__all__ = ["MODEL_KINDS", "NATIVE_KINDS", "NativeBuildError", "NativeTwin", "build_native",
           "build_native_fmu", "build_native_model", "built_config", "clocked_config",
           "compiler", "native_archive", "native_fmu_dir", "native_fmu_path", "native_twin",
           "pop_notes"]

#: the shared C sources (``fmus/native/`` in the repository, package data of
#: delaycomp.fmus): the FMI layer, the linear algebra, DOP853, the host, export-c's templates
SOURCE_DIR = FMU_ROOT / "native"
#: FMU kind -> the model's C file (in its folder, ``native_twin``)
NATIVE_KINDS: dict[str, str] = {kind: f"{spec.native}.c" for kind, spec in FMUS.items()
                                if spec.native and not spec.template}
#: FMU kind of a user model -> its C file; with it model.c, generated from the model file
#: by ``delaycomp.fmu.translate``
MODEL_KINDS: dict[str, str] = {kind: f"{spec.native}.c" for kind, spec in FMUS.items()
                               if spec.native and spec.template}
#: the FMI layer, in every native FMU, and its headers (``native.h`` declares what
#: ``fmi2.c`` and ``native.c`` share with the models)
COMMON_SOURCES = ("fmi2.c", "core.c", "native.c", "pyrepr.c")
COMMON_HEADERS = ("native.h", "core.h", "pyrepr.h")
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: the FMI 3.0 headers (``build --fmi 3``: fmi3.c in place of fmi2.c)
FMI3_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
#: the FMI versions a native FMU is built for
FMI_VERSIONS = (2, 3)
CFLAGS = ("-std=c11", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-ffp-contract=off",
          "-Wall", "-Wextra", "-Werror")


@dataclass(frozen=True)
class NativeTwin:
    """The native twin of one FMU kind, as its folder declares it.

    ``fmus/<kind>/<name>.c`` (the model's maths: the ``model_*`` functions of
    ``native.h``), ``<name>.h`` (its dimensions and ``ModelData``) and ``<name>.toml`` (its
    manifest: ``uses``, the shared sources of ``fmus/native/`` it needs beside the FMI
    layer, and ``value_references``, the ``VR_*`` macros its C addresses, each naming a
    variable of the Python twin's table). The FMI layer knows no model: adding a model
    is its folder and its row of ``delaycomp.fmu.build.FMUS``.
    """

    kind: str
    folder: Path
    name: str
    uses: tuple[str, ...]
    value_references: dict[str, str]
    #: FMI 3.0 (``[fmi3]``): structural parameters (name -> description) and the arrays
    #: (name -> its dimensions, each a structural parameter)
    structural: dict[str, str] = field(default_factory=dict)
    arrays: dict[str, list[str]] = field(default_factory=dict)
    #: FMI 3.0 (``[fmi3.clock]``): the clock of a clocked build (``name``, ``interval``:
    #: the parameter that gives it, ``description``); empty: no clocked variant
    clock: dict[str, str] = field(default_factory=dict)
    #: FMI 3.0 (``[fmi3] optional``): arrays a build may have no elements of (the channel's
    #: trace of length 0): left out, with the structural parameters that size only them
    optional: tuple[str, ...] = ()

    @property
    def files(self) -> tuple[Path, ...]:
        """The model's own files: its C, its header and its manifest."""
        return tuple(self.folder / f"{self.name}{ext}" for ext in (".c", ".h", ".toml"))

    def sources(self, fmi: int = 2) -> list[str]:
        """The ``.c`` files of an FMU of this kind (model.c, generated, last), with the
        FMI layer of version ``fmi`` (``fmi3.c`` in place of ``fmi2.c`` for 3)."""
        common = [f"fmi{fmi}.c", *COMMON_SOURCES[1:]]
        return [*common, *self.uses, f"{self.name}.c",
                *(["model.c"] if FMUS[self.kind].template else [])]

    def headers(self) -> list[str]:
        """The headers beside them (config.h and the FMI headers apart)."""
        return [*COMMON_HEADERS, *(u.removesuffix(".c") + ".h" for u in self.uses),
                f"{self.name}.h",
                *(["model.h", "model_config.h"] if FMUS[self.kind].template else [])]

    def path_of(self, file: str) -> Path:
        """Where a source or header of ``sources`` / ``headers`` lives (the
        generated model files apart)."""
        return self.folder / file if file.startswith(self.name + ".") else SOURCE_DIR / file


def native_twin(kind: str) -> NativeTwin:
    """The native twin of ``kind`` (a key of ``NATIVE_KINDS`` or ``MODEL_KINDS``),
    read from its folder's manifest.

    Raises
    ------
    ValueError
        ``kind`` has no native twin, or its manifest is not as ``NativeTwin`` says.
    """
    spec = FMUS.get(kind)
    if spec is None or not spec.native:
        raise ValueError(f"kind {kind!r} is not allowed for a native FMU: must be one of "
                         f"{', '.join((*NATIVE_KINDS, *MODEL_KINDS))}")
    manifest = spec.folder / f"{spec.native}.toml"
    data = tomllib.loads(manifest.read_text(encoding="utf-8"))
    uses, vrs = data.get("uses", []), data.get("value_references", {})
    fmi3 = data.get("fmi3", {})
    structural, arrays = fmi3.get("structural", {}), fmi3.get("arrays", {})
    clock = fmi3.get("clock", {})
    optional = fmi3.get("optional", [])
    if (set(data) - {"uses", "value_references", "fmi3"}
            or set(clock) - {"name", "interval", "description"}
            or (clock and not {"name", "interval"} <= set(clock))
            or not all(isinstance(u, str) and u.endswith(".c") for u in uses)
            or not all(isinstance(v, str) for v in vrs.values())
            or set(fmi3) - {"structural", "arrays", "clock", "optional"}
            or not all(a in arrays for a in optional)
            or not all(isinstance(v, str) for v in structural.values())
            or not all(isinstance(d, list) and all(x in structural for x in d)
                       for d in arrays.values())):
        raise ValueError(f"{manifest}: a native manifest has `uses` (a list of .c files of "
                         "fmus/native/), `value_references` (macro = variable name) and "
                         "`[fmi3]`: `structural` (name = description), `arrays` (name = "
                         "its dimensions, structural parameters), `clock` (name, interval, "
                         "description) and `optional` (arrays a build may leave empty)")
    return NativeTwin(kind, spec.folder, spec.native, tuple(uses), dict(vrs),
                      dict(structural), {k: list(v) for k, v in arrays.items()}, dict(clock),
                      tuple(optional))


def pop_notes() -> list[str]:
    """The notes about platforms left out since the last call (each note once per
    process; ``delaycomp.fmu.toolchain.pop_notes``)."""
    return toolchain.pop_notes()


def platforms_tag() -> str:
    """The platforms native FMUs get here and whether Zig builds them, as a name part of
    the build cache (an FMU built by a system compiler is not one built by Zig)."""
    built = toolchain.targets()
    return "+".join(built) + ("-zig" if any(c.zig for c in built.values()) else "")


def compiler() -> list[str]:
    """The C compiler command for this machine (``delaycomp.fmu.toolchain.host_compiler``:
    ``$CC`` if set, else ``zig cc``, else ``cc``, ``gcc`` or ``clang``).

    Raises
    ------
    NativeBuildError
        No compiler found; the message names what to install.
    """
    return toolchain.host_compiler()


def fmi_header_dir() -> Path:
    """fmpy's copy of the FMI 2.0 headers."""
    import fmpy

    return Path(fmpy.__file__).resolve().parent / "c-code"


def sources_digest() -> str:
    """Digest of the C sources and this version (names the native build cache)."""
    h = hashlib.sha256(__version__.encode())
    shared = sorted((*SOURCE_DIR.glob("*.c"), *SOURCE_DIR.glob("*.h")))
    for path in (*shared, SOURCE_DIR / "README.md",
                 *(f for kind in (*NATIVE_KINDS, *MODEL_KINDS)
                   for f in native_twin(kind).files)):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    h.update(Path(__file__).read_bytes())
    h.update((Path(__file__).parent / "translate.py").read_bytes())  # generates model.c
    return h.hexdigest()[:12]


def _c_string(text: str) -> str:
    return json.dumps(text)  # a JSON string literal of ASCII text is a C string literal


def _python_table(kind: str, config: dict) -> Element:
    """The Python FMU's modelDescription for ``kind`` and ``config`` (not written to disk)."""
    from delaycomp.fmu.slaves import slave_class

    cls, cfg = slave_class(kind, config)
    slave = cls(instance_name="native-build", resources=None, config=cfg)
    return slave.to_xml(dict(FMUS[kind].options))


def _exact_starts(root: Element, start: dict) -> None:
    """Each start value of a build's ``start`` table, in the table tree as it reads back
    exactly (``delaycomp.fmu.build.start_text``: pythonfmu writes 16 digits); config.h and
    the modelDescription are made from the tree. A name that is no variable of the FMU
    is refused."""
    from delaycomp.fmu.build import start_text

    variables = root.find("ModelVariables")
    assert variables is not None  # the table tree (slave.to_xml) has its variables
    by_name = {sv.get("name"): sv for sv in variables}
    for name, value in start.items():
        sv = by_name.get(name)
        typed = next(iter(sv)) if sv is not None else None
        if typed is None or typed.get("start") is None:
            raise ValueError(f"no parameter {name!r} with a start value in the "
                             "modelDescription")
        typed.set("start", start_text(typed.tag, value))


def _variables(root: Element) -> list[dict]:
    out = []
    variables = root.find("ModelVariables")
    assert variables is not None  # the table tree (slave.to_xml) has its variables
    for sv in variables:
        typ = next(iter(sv))
        # every variable of the table tree has its valueReference
        out.append({"name": sv.get("name"), "vr": int(cast(str, sv.get("valueReference"))),
                    "causality": sv.get("causality"), "type": typ.tag,
                    "start": typ.get("start")})
    if [v["vr"] for v in out] != list(range(len(out))):
        raise NativeBuildError("value references are not 0 .. N-1 in table order")
    return out


def _config_h(twin: NativeTwin, config: dict, root: Element, guid: str,
              table3: Fmi3Table | None = None) -> str:
    """config.h of one build: the Python twin's variable table as C, the model's header
    (``MODEL_HEADER``), and the value reference of each macro of its manifest; with
    ``table3``, an FMI 3.0 build's (``FMI_MAJOR 3`` and the FMI 3.0 variables of
    ``delaycomp.fmu.fmi3.config_block``)."""
    variables = _variables(root)
    ins = [v for v in variables if v["causality"] == "input"]
    outs = [v for v in variables if v["causality"] == "output"]
    code = {"Real": "r", "Integer": "i", "Boolean": "b", "String": "s"}
    caus = {"parameter": "p", "input": "i", "output": "o"}
    strings = [v for v in variables if v["type"] == "String"]
    lines = [
        "/* Generated by `delaycomp build --native` from the Python FMU's variable table:",
        f" * {root.get('modelName')}, configuration {json.dumps(config, sort_keys=True)}. */",
        "#ifndef DELAYCOMP_CONFIG_H", "#define DELAYCOMP_CONFIG_H", "",
        f"#define FMI_MAJOR {2 if table3 is None else 3}",
        f"#define MODEL_HEADER {_c_string(twin.name + '.h')}",
        f"#define INSTANTIATION_TOKEN {_c_string(guid)}",
        f"#define NIN {len(ins)}",
        f"#define NOUT {len(outs)}",
        f"#define NVR {len(variables)}",
        f"#define NSTRING {len(strings)}",
        f"#define OUTPUT_NAMES {_c_string(repr([v['name'] for v in outs]))}",
    ]
    by_name = {v["name"]: v["vr"] for v in variables}
    for macro, name in twin.value_references.items():
        if name not in by_name:
            raise NativeBuildError(f"{twin.name}.toml: {macro} names {name!r}, which is no "
                                   f"variable of {root.get('modelName')}")
        lines.append(f"#define {macro} {by_name[name]}")
    lines.append(f"#define VR_INPUT {ins[0]['vr']}")
    lines.append(f"#define VR_OUTPUT {outs[0]['vr']}")
    # the C code addresses matrices and vectors as contiguous blocks: check that they are
    for group in (ins, outs):
        if [v["vr"] for v in group] != list(range(group[0]["vr"], group[0]["vr"] + len(group))):
            raise NativeBuildError("inputs and outputs must have consecutive value references")
    lines += ["", "static const char *const VAR_NAME[NVR] = {"]
    lines += [f"    {_c_string(v['name'])}," for v in variables]
    lines += ["};", f"static const char VAR_TYPE[NVR + 1] = "
              f"{_c_string(''.join(code[v['type']] for v in variables))};",
              f"static const char VAR_CAUSALITY[NVR + 1] = "
              f"{_c_string(''.join(caus[v['causality']] for v in variables))};",
              "static const double REAL_START[NVR] = {"]
    lines += [f"    {float(v['start']).hex() if v['type'] == 'Real' and v['start'] else '0.0'},"
              for v in variables]
    lines += ["};", "static const int BOOLEAN_START[NVR] = {"]
    lines += [f"    {1 if v['type'] == 'Boolean' and v['start'] == 'true' else 0},"
              for v in variables]
    lines += ["};", "static const int INTEGER_START[NVR] = {"]
    lines += [f"    {int(v['start']) if v['type'] == 'Integer' and v['start'] else 0},"
              for v in variables]
    lines += ["};"]
    if strings:
        slots = {v["vr"]: k for k, v in enumerate(strings)}
        lines += ["static const char *const STRING_START[NSTRING] = {"]
        lines += [f"    {_c_string(v['start'] or '')}," for v in strings]
        lines += ["};", "static const int STRING_SLOT[NVR] = {"]
        lines += [f"    {slots.get(v['vr'], -1)}," for v in variables]
        lines += ["};"]
    if table3 is not None:
        from delaycomp.fmu.fmi3 import config_block

        lines += ["", *config_block(table3)]
    lines += ["", "#endif", ""]
    return "\n".join(lines)


def _model_config_h(translation, root: Element) -> str:
    """``model_config.h`` of a model FMU: where its numeric parameters (in the order of
    ``p`` of model.c) and its String parameters with choices (in the order of model.c's
    branches) are, by value reference."""
    variables = {v["name"]: v for v in _variables(root)}
    numeric = [variables[name]["vr"] if name in variables else -1
               for name in translation.numeric]
    names = sorted(translation.model.choices)
    widest = max((len(translation.model.choices[k]) for k in names), default=1)
    lines = ["/* Generated by `delaycomp build --native` for model "
             f"{translation.model.name}: its parameters by value reference. */",
             "#ifndef DELAYCOMP_MODEL_CONFIG_H", "#define DELAYCOMP_MODEL_CONFIG_H", "",
             f"#define MODEL_NAME {_c_string(translation.model.name)}",
             f"#define MODEL_ZOH {int(translation.model.control == 'zoh')}",
             f"#define MODEL_HAS_PREDICTOR {int(translation.model.predictor is not None)}",
             f"#define NCHOICE {len(names)}",
             "static const int PARAM_VR[MODEL_NP > 0 ? MODEL_NP : 1] = {"
             + ", ".join(map(str, numeric or [-1])) + "};"]
    rows = names or [None]
    lines.append("static const char *const CHOICE_NAME[NCHOICE > 0 ? NCHOICE : 1] = {"
                 + ", ".join(_c_string(k or "") for k in rows) + "};")
    lines.append("static const int CHOICE_VR[NCHOICE > 0 ? NCHOICE : 1] = {"
                 + ", ".join(str(variables[k]["vr"]) if k else "0" for k in rows) + "};")
    lines.append("static const int CHOICE_INDEX_VR[NCHOICE > 0 ? NCHOICE : 1] = {"
                 + ", ".join(str(variables[f"{k}_index"]["vr"]) if k else "0"
                             for k in rows) + "};")
    lines.append("static const int CHOICE_COUNT[NCHOICE > 0 ? NCHOICE : 1] = {"
                 + ", ".join(str(len(translation.model.choices[k])) if k else "0"
                             for k in rows) + "};")
    lines.append(f"static const char *const CHOICE_VALUES[NCHOICE > 0 ? NCHOICE : 1][{widest}]"
                 " = {")
    for k in rows:
        values = translation.model.choices[k] if k else ("",)
        lines.append("    {" + ", ".join(_c_string(v) for v in values) + "},")
    lines += ["};", "", "#endif", ""]
    return "\n".join(lines)


def check_closed_form(kind: str, translation) -> None:
    """The native controller's closed-form predictor composes the model's exact step over
    the segments of the window (the exact flow composes): a model that gives
    ``predictor`` needs a ``step`` that translates."""
    from delaycomp.fmu.translate import TranslationError

    model = translation.model
    if kind != "model_controller" or model.predictor is None or any(
            name == "step" for name, _ in translation.functions):
        return
    suffix = "; the Python FMUs run it"
    why = translation.untranslated.get("step", "").removesuffix(suffix) or (
        f"model {model.name}: it gives predictor(x, segments, p) but no step(x, u, h, p)")
    raise TranslationError(f"{why}: the native controller's closed-form predictor composes "
                           f"the exact step over the window{suffix}")


def _native_description(kind: str, root: Element, ident: str, guid: str,
                        sources: list[str]) -> bytes:
    root.set("guid", guid)
    root.set("generationTool", f"delaycomp {__version__} (native C)")
    root.attrib.pop("generationDateAndTime", None)  # a rebuild gives the same file
    cs = root.find("CoSimulation")
    assert cs is not None  # the table tree (slave.to_xml) is a co-simulation FMU's
    cs.set("needsExecutionTool", "false")
    cs.set("canBeInstantiatedOnlyOncePerProcess", "false")
    cs.set("canNotUseMemoryManagementFunctions", "true")
    cs.set("modelIdentifier", ident)
    files = Element("SourceFiles")
    for name in sources:
        SubElement(files, "File", attrib={"name": name})
    cs.insert(0, files)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def build_native_fmu(kind: str, out_dir: Path, config: dict | None = None,
                     file_name: str | None = None, fmi: int = 2) -> Path:
    """Build the native FMU ``kind`` (``delay``, ``plant`` or ``controller``) into
    ``out_dir`` and return its path.

    Parameters
    ----------
    kind : str
        One of ``NATIVE_KINDS``, or ``model_plant`` (``MODEL_KINDS``) with
        ``config = {"model": FILE.py}``: the model's ``f`` (and ``step``) translated to C
        by ``delaycomp.fmu.translate``, the flow solved by ``ode.c``.
    out_dir : Path
        Output folder (created).
    config : dict, optional
        The build configuration, as for ``delaycomp.fmu.build.build_fmu`` (dimensions
        ``n``, ``m``; names; an optional ``start`` table). Default: the scalar loop.
    file_name : str, optional
        Default ``<modelIdentifier>.fmu``.
    fmi : int, optional
        The FMI version, 2 (default) or 3 (``delaycomp.fmu.fmi3``: the vectors and
        matrices as arrays sized by structural parameters, the binaries in FMI 3.0's
        platform folders, ``sources/buildDescription.xml``). With 3, ``config`` may
        say ``"clocked": True`` for a kind whose manifest has ``[fmi3.clock]`` (the LTI
        controller): its sampling driven by an FMI 3.0 clock of interval T.

    Raises
    ------
    NativeBuildError
        No C compiler, or it failed (its output is in the message).
    ValueError
        A kind without a native twin, or a bad dimension.
    delaycomp.fmu.translate.TranslationError
        The model's ``f`` does not translate (the function, the operation, the line).
    """
    from delaycomp.fmu.slave import pinned_guid

    if fmi not in FMI_VERSIONS:
        raise ValueError(f"fmi = {fmi!r} is not allowed: must be 2 or 3 (the FMI version)")
    twin = native_twin(kind)
    clocked = bool((config or {}).get("clocked"))
    if clocked and (fmi != 3 or not twin.clock):
        raise ValueError(f"clocked = true is not allowed for {'FMI 2.0' if fmi != 3 else kind}: "
                         "a clocked controller is an FMI 3.0 LTI controller (fmi = 3, kind "
                         f"{', '.join(k for k in NATIVE_KINDS if native_twin(k).clock)})")
    built = toolchain.targets()
    config, translation, ident = _native_config(
        kind, {k: v for k, v in config.items() if k != "clocked"} if config else config)
    if clocked:
        config = {**config, "clocked": True}
    root = _python_table(kind, {k: v for k, v in config.items() if k != "clocked"})
    _exact_starts(root, config.get("start") or {})
    full = {**config, "version": __version__, **({"fmi": 3} if fmi == 3 else {})}
    guid = "{" + str(pinned_guid(f"{ident}/native" + ("/fmi3" if fmi == 3 else ""),
                                 full)) + "}"
    sources = twin.sources(fmi)
    table3 = None
    if fmi == 3:
        from delaycomp.fmu import fmi3

        table3 = fmi3.fmi3_table(root, twin.structural, twin.arrays,
                                 twin.clock if clocked else None, twin.optional)
        description = fmi3.model_description(
            root, table3, ident, guid, f"delaycomp {__version__} (native C)")
    else:
        description = _native_description(kind, root, ident, guid, sources)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / (file_name or f"{ident}.fmu")
    from delaycomp.progress import detail

    detail(f"building {ident} (native{', FMI 3.0' if fmi == 3 else ''}, "
           f"{_compilers_text(built, fmi)}) into {out_dir} ...")
    with tempfile.TemporaryDirectory(prefix="delaycomp-native-") as tmp:
        stage = Path(tmp) / "fmu"
        src = stage / "sources"
        src.mkdir(parents=True)
        _write_sources(src, twin, translation, root, fmi)
        (src / "config.h").write_text(_config_h(twin, config, root, guid, table3),
                                      encoding="utf-8")
        if fmi == 3:
            from delaycomp.fmu.fmi3 import build_description

            (src / "buildDescription.xml").write_bytes(build_description(ident, sources))
        _compile_binaries(kind, stage, src, ident, sources, built, fmi)
        _write_metadata(kind, stage, description, full)
        zip_folder(stage, target)
    return target


def _compilers_text(built: dict, fmi: int) -> str:
    """What ``-v`` says of a build: the binaries folders each compiler fills, this
    machine's first (``linux64 aarch64-linux win64 darwin64 aarch64-darwin with zig
    0.17.1``)."""
    by: dict[str, list[str]] = {}
    for name, c in built.items():
        by.setdefault(c.label, []).extend(toolchain.folders(name, fmi))
    return "; ".join(f"{' '.join(dict.fromkeys(fs))} with {label}"
                     for label, fs in by.items())


def _native_config(kind: str, config: dict | None
                   ) -> tuple[dict, Translation | None, str]:
    """The checked build configuration, the model's translation (None but for a model kind)
    and the model identifier."""
    if kind in MODEL_KINDS and not (config or {}).get("model"):
        raise ValueError(f"a native {kind} FMU needs config = {{'model': FILE.py}}")
    config = dict(DEFAULT_CONFIG[kind] if config is None else config)
    check_dimensions(config)
    if kind not in MODEL_KINDS:
        return config, None, FMUS[kind].model_identifier
    from delaycomp.fmu.translate import translate
    from delaycomp.maths.model import load_model

    config = {"model": str(Path(config["model"]).resolve()),
              **({"start": config["start"]} if config.get("start") else {})}
    translation = translate(load_model(config["model"]))
    check_closed_form(kind, translation)
    return config, translation, model_identifier(kind, config)


def _write_sources(src: Path, twin: NativeTwin, translation: Translation | None,
                   root: Element, fmi: int = 2) -> None:
    """The twin's C sources and headers (a model's translated to C) and the FMI headers
    into ``src``."""
    generated = {}
    if translation is not None:
        generated = {**translation.c_files(),
                     "model_config.h": _model_config_h(translation, root)}
    for name in (*twin.sources(fmi), *twin.headers()):
        if name in generated:
            (src / name).write_text(generated[name], encoding="utf-8")
        else:
            shutil.copy2(twin.path_of(name), src / name)
    for name in FMI_HEADERS if fmi == 2 else FMI3_HEADERS:
        shutil.copy2(fmi_header_dir() / name, src / name)


def _compile_binaries(kind: str, stage: Path, src: Path, ident: str, sources: list[str],
                      built: dict, fmi: int) -> None:
    """Compile the sources for each platform of ``built`` (platform -> its
    ``toolchain.Compiler``), the compilers at once, each into a folder of its own beside
    ``stage`` (Zig and MinGW write import libraries and debug files beside a DLL), then
    place the libraries in ``stage/binaries`` (``toolchain.place``); the first failure
    raises."""
    builds = []
    for platform, c in built.items():  # the compilers run at once
        lib = stage.parent / "objects" / platform / f"{ident}{toolchain.suffix(platform)}"
        lib.parent.mkdir(parents=True)
        # a macOS library names itself by its file, not by this build's folder
        own = ([f"-Wl,-install_name,@rpath/{lib.name}"] if lib.suffix == ".dylib" else [])
        argv = [*c.argv, *CFLAGS, *c.flags, *own, "-I", str(src), "-o", str(lib),
                *(str(src / s) for s in sources), "-lm"]
        builds.append((platform, lib, c.label, subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)))
    failed = []
    for platform, _, label, proc in builds:
        _, err = proc.communicate()
        if proc.returncode != 0:
            failed.append(f"compiling the native {kind} FMU for {platform} failed "
                          f"({label}):\n{err.strip()}")
    if failed:
        raise NativeBuildError(failed[0])
    toolchain.place({platform: lib for platform, lib, _, _ in builds}, stage / "binaries",
                    ident, fmi)


def _write_metadata(kind: str, stage: Path, description: bytes, full: dict) -> None:
    """modelDescription.xml, the build configuration and the documentation into
    ``stage``."""
    (stage / "modelDescription.xml").write_bytes(description)
    res = stage / "resources"
    res.mkdir()
    # sources: what a run checks an FMU of --fmu-dir against (the cache's folders are
    # named by it); not part of the GUID (``full`` without it)
    (res / CONFIG_NAME).write_text(json.dumps({**full, "native": True,
                                               "sources": sources_digest()}, sort_keys=True),
                                   encoding="utf-8")
    doc = stage / "documentation"
    doc.mkdir()
    shutil.copy2(FMUS[kind].folder / "README.md", doc / "README.md")
    shutil.copy2(SOURCE_DIR / "README.md", doc / "native.md")


def build_native(out_dir: Path, fmi: int = 2, clocked: bool = False) -> list[Path]:
    """Build the three native FMUs of the scalar LTI loop (default dimensions), for FMI
    version ``fmi`` (2 or 3); ``clocked`` (FMI 3.0): the controller driven by a clock."""
    return [build_native_fmu(kind, out_dir, clocked_config({}, kind, clocked) or None, fmi=fmi)
            for kind in NATIVE_KINDS if kind in LOOP_KINDS]


def clocked_config(config: dict, kind: str, clocked: bool) -> dict:
    """``config`` with ``clocked`` where asked and the kind has a clocked variant."""
    return {**config, "clocked": True} if clocked and native_twin(kind).clock else config


def build_native_model(model_path: str | Path, out_dir: Path, fmi: int = 2) -> list[Path]:
    """The native twins of ``delaycomp.fmu.build.build_model``: the model's plant and
    predictor-controller as C FMUs (``f``, ``k`` and ``step`` translated by
    ``delaycomp.fmu.translate``), and native delays of the model's widths (same file names
    as the Python build).

    Raises
    ------
    delaycomp.fmu.translate.TranslationError
        The model does not translate (one line: the function, the operation, the line).
    NativeBuildError
        No C compiler, or it failed.
    """
    from delaycomp.fmu.build import DEFAULT_CONFIG
    from delaycomp.maths.model import load_model

    model = load_model(model_path)  # checks the interface before any build
    paths = [build_native_fmu(kind, out_dir, {"model": str(model_path)}, fmi=fmi)
             for kind in MODEL_KINDS]
    for width in sorted({model.n, model.m}):
        cfg = {"n": width}
        name = None if cfg == DEFAULT_CONFIG["delay"] else f"DelaycompDelay_n{width}.fmu"
        paths.append(build_native_fmu("delay", out_dir, cfg, name, fmi=fmi))
    return paths


def native_fmu_dir(fmi: int = 2) -> Path:
    """Build cache of native FMUs, beside the Python FMUs' cache, per source digest (the
    FMI 3.0 ones in a folder of their own: same file names)."""
    from delaycomp.fmu.cache import default_fmu_dir

    return default_fmu_dir().parent / (f"native-{__version__}-{sources_digest()}-"
                                       f"{platforms_tag()}" + ("-fmi3" if fmi == 3 else ""))


def native_fmu_path(kind: str, config: dict, fmu_dir: Path | None = None,
                    fmi: int = 2) -> Path:
    """The native FMU for ``kind`` and ``config`` in ``fmu_dir`` (default: the cache;
    FMI 3.0 FMUs in its subfolder ``fmi3``), built there if missing; an FMU already there
    is checked as ``delaycomp.fmu.cache.check_fmu`` does, and must be native, of FMI
    version ``fmi``."""
    from delaycomp.fmu.cache import cache_hit, fmu_file_name

    own = fmu_dir is not None
    if fmu_dir is None:
        fmu_dir = native_fmu_dir(fmi)
    elif fmi == 3:
        fmu_dir = Path(fmu_dir) / "fmi3"
    fmu_dir = Path(fmu_dir)
    path = fmu_dir / fmu_file_name(kind, config)
    if not path.exists():
        from delaycomp.tmpfiles import build_lock

        fmu_dir.mkdir(parents=True, exist_ok=True)
        with build_lock(path):  # parallel first runs: one compiles, the others wait
            if not path.exists():
                build_native_fmu(kind, fmu_dir, config, path.name, fmi=fmi)
                cache_hit(path, model_identifier(kind, config), built=True)
                return path
    _check_native(path, kind, config, fmi, own)
    cache_hit(path, model_identifier(kind, config))
    return path


def _check_native(path: Path, kind: str, config: dict, fmi: int, own: bool) -> None:
    """``check_fmu`` (``own``: a folder of the caller's, whose FMUs must be built from these
    sources), and native, of FMI version ``fmi``."""
    from delaycomp.errors import BadFileError
    from delaycomp.fmu.cache import check_fmu, check_sources

    check_fmu(path, kind, config, sources=own)
    built = built_config(path)
    if not built.get("native"):
        raise BadFileError(path, "is a Python FMU, not a native one (use another "
                                 "--fmu-dir, or delete it to rebuild)")
    if own:
        check_sources(path, built, sources_digest())
    if built.get("fmi", 2) != fmi:
        raise BadFileError(path, f"is an FMI {built.get('fmi', 2)}.0 FMU, this run needs FMI "
                                 f"{fmi}.0 (use another --fmu-dir, or delete it to rebuild)")


def built_config(path: Path) -> dict:
    """The build configuration a delaycomp FMU carries (``resources/delaycomp_fmu.json``:
    its configuration, ``version``, ``sources``, and ``native`` and ``fmi`` for a native
    one); ``{}`` where it has none."""
    with zipfile.ZipFile(path) as zf:
        try:
            return json.loads(zf.read(f"resources/{CONFIG_NAME}"))
        except (KeyError, ValueError):
            return {}


def native_archive(src: Path, dest: Path, fmu_dir: Path | None = None) -> Path:
    """Copy the SSP archive ``src`` to ``dest`` with each delaycomp FMU of ``resources/``
    replaced by its native twin (same file name, variables and value references, built
    for the configuration the FMU carries). The SSD, the parameter sets and any other file
    are copied unchanged, so libcosim, Ecos and our master run the archive as before.

    A model file's plant and controller are rebuilt from the model file their Python FMU
    carries (``resources/delaycomp_model_<id>.py``), under its own name, so the native
    twin has the same modelIdentifier.

    The twins come from the native build cache, ``fmu_dir`` (default: ``native_fmu_dir``),
    built there where missing: each kind and configuration is compiled once, however many
    archives hold it.

    Raises
    ------
    ValueError
        An FMU of the archive has no native twin (another tool's FMU).
    delaycomp.fmu.translate.TranslationError
        A model FMU's model does not translate to C.
    """
    src, dest = Path(src), Path(dest)
    part = dest.with_name(dest.name + ".part")
    with tempfile.TemporaryDirectory(prefix="delaycomp-native-ssp-") as tmp, \
            zipfile.ZipFile(src) as zin, \
            zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename.startswith("resources/") and item.filename.endswith(".fmu"):
                inner = Path(tmp) / Path(item.filename).name
                inner.write_bytes(data)
                if _is_native(inner):  # a native FMU already (delaycomp build packs them)
                    zout.writestr(item, data)
                    continue
                kind, config = _twin_of(inner, item.filename, Path(tmp) / "models")
                # from the native build cache: a twin of the same kind and configuration
                # (a model's named by its content) is compiled once, for every archive
                data = native_fmu_path(kind, config, fmu_dir).read_bytes()
            zout.writestr(item, data)
    part.replace(dest)
    return dest


def _is_native(fmu: Path) -> bool:
    """A delaycomp native FMU (its build configuration says so)?"""
    with zipfile.ZipFile(fmu) as zf:
        try:
            return bool(json.loads(zf.read(f"resources/{CONFIG_NAME}")).get("native"))
        except (KeyError, ValueError):
            return False


def _twin_of(fmu: Path, label: str, models: Path) -> tuple[str, dict]:
    """``(kind, config)`` of the native twin of the delaycomp FMU ``fmu``."""
    from fmpy import read_model_description

    from delaycomp.fmu.build import model_identifier

    kinds = {spec.model_identifier: kind for kind, spec in FMUS.items()
             if kind in NATIVE_KINDS}
    ident = read_model_description(str(fmu)).coSimulation.modelIdentifier
    with zipfile.ZipFile(fmu) as zf:
        names = set(zf.namelist())
        config = json.loads(zf.read(f"resources/{CONFIG_NAME}")) if (
            f"resources/{CONFIG_NAME}" in names) else {}
        mid, name = config.get("model_id"), config.get("model_name")
        module = f"resources/delaycomp_model_{mid}.py"
        if ident in kinds:
            return kinds[ident], {k: v for k, v in config.items()
                                  if k not in ("version", "native", "sources")}
        kind = next((k for k in MODEL_KINDS if mid and name and module in names
                     and ident == f"{FMUS[k].model_identifier}_{mid}"), None)
        if kind is None:
            raise ValueError(f"{label} ({ident}) is not allowed in a native archive: native "
                             "FMUs exist for delaycomp's delay, network channel, LTI plant "
                             "and controller, and a model file's plant and controller")
        folder = models / str(mid)
        folder.mkdir(parents=True, exist_ok=True)
        model_file = folder / f"{name}.py"
        model_file.write_bytes(zf.read(module))
    built_with = config.get("version")
    config = {"model": str(model_file)}
    if model_identifier(kind, config) != ident:
        raise ValueError(f"{label} ({ident}) is not allowed in a native archive: it was "
                         f"built by delaycomp {built_with!r}, this is "
                         f"{__version__!r} (rebuild the archive)")
    return kind, config
