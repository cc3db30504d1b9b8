"""Layers as folders, imports only downward (DESIGN.md, issue 26).

Each module of the installed namespace belongs to one unit (a folder of ``delaycomp/``, the
base files, the face, ``orchestrator/``, ``fmus/``, ``reference/``) and each unit stands on
a floor. A module may import its own unit's modules and anything on a lower floor, never a
unit on its floor or above; the modules import each other in no ring; the units stand on
at most eight floors, measured from the imports (the longest chain of units); and no module
takes a private name (``_name``) of another. The imports, module-level or inside functions,
are read from the sources (ast); ``importlib.import_module`` of a string is not an arrow
(the in-process engine loads the FMUs' slave modules that way, as a host does).

``python -m pytest tests/test_layers.py -q -rA`` prints the floors and the units on each
(``test_floors_of_the_units``).
"""

from __future__ import annotations

import ast
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

#: the units, their floors (1 = the ground) and what they hold; a module takes the unit of
#: its longest prefix
UNITS = {
    # 1: the light base: errors, names, files, child processes, progress bars, figures;
    #    the reference computations share no code with delaycomp
    "delaycomp": ("base", 1), "delaycomp.reference": ("reference", 1),
    # 2: the maths, free of FMI (what the Python FMUs bundle)
    "delaycomp.maths": ("maths", 2),
    # 3: the system model: the typed loop, loop files, rewrites on roles
    "delaycomp.system": ("system", 3),
    # 4: the paper as data; the FMUs' build side (base slave, registry, cache, native build)
    "delaycomp.paper": ("paper", 4), "delaycomp.fmu": ("fmu", 4),
    # 5: the master and the wiring of a loop; the FMUs' slave modules
    "delaycomp.orchestrator": ("orchestrator", 5), "delaycomp.fmus": ("fmus", 5),
    # 6: what delaycomp writes and reads (SSP, outputs, your loop's FMUs, C)
    "delaycomp.formats": ("formats", 6),
    # 7: studies over many loops; verification against references and other masters
    "delaycomp.studies": ("studies", 7), "delaycomp.verify": ("verify", 7),
    # 8: the face
    "delaycomp.api": ("face", 8), "delaycomp.cli": ("face", 8),
    "delaycomp.__main__": ("face", 8),
}
MAX_FLOORS = 8
ROOTS = {"delaycomp": REPO / "delaycomp", "delaycomp.orchestrator": REPO / "orchestrator",
         "delaycomp.fmus": REPO / "fmus", "delaycomp.reference": REPO / "reference"}


def unit(module: str) -> tuple[str, int] | None:
    parts = module.split(".")
    for i in range(len(parts), 0, -1):
        if ".".join(parts[:i]) in UNITS:
            return UNITS[".".join(parts[:i])]
    return None


def modules():
    for prefix, root in ROOTS.items():
        for path in sorted(root.rglob("*.py")):
            rel = path.relative_to(root).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            yield ".".join([prefix, *parts]), path, path.name == "__init__.py"


CASES = list(modules())
NAMES = {m for m, _, _ in CASES}


def _module_of(target: str) -> str | None:
    """The module of ours that an import target names (``a.b.name`` -> ``a.b``)."""
    while target and target not in NAMES:
        target = target.rpartition(".")[0]
    return target or None


def imports(module: str, path: Path, is_package: bool):
    """(target, imported names, line) of every import in ``path``; a relative import is
    made absolute."""
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, (), node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            names = tuple(a.name for a in node.names)
            yield target, names, node.lineno
            for a in names:  # from . import x: x may be a module
                if f"{target}.{a}" in NAMES:
                    yield f"{target}.{a}", (), node.lineno


def edges() -> dict[str, set[str]]:
    """module -> the modules of ours it imports."""
    out: dict[str, set[str]] = {}
    for module, path, is_package in CASES:
        out[module] = {t for target, _, _ in imports(module, path, is_package)
                       if target.startswith("delaycomp")
                       and (t := _module_of(target)) and t != module}
    return out


EDGES = edges()


@pytest.mark.parametrize("module,path,is_package", CASES, ids=[m for m, _, _ in CASES])
def test_imports_point_down(module, path, is_package):
    own = unit(module)
    assert own is not None, f"{module} has no unit in UNITS"
    bad = sorted(f"{t} ({unit(t)[0]}, floor {unit(t)[1]})" for t in EDGES[module]
                 if unit(t)[0] != own[0] and unit(t)[1] >= own[1])
    assert not bad, f"{module} ({own[0]}, floor {own[1]}) imports sideways or up: {bad}"


def face_imports(module: str, path: Path, is_package: bool) -> list[str]:
    """The imports of the package's face (``delaycomp/__init__.py``, which hands on the
    API) in a module: ``import delaycomp`` or a name of the face (``from delaycomp import
    __version__``); a submodule taken from it (``from delaycomp import progress``) is not."""
    out = []
    for target, names, line in imports(module, path, is_package):
        if target == "delaycomp" and (not names or any(
                f"delaycomp.{n}" not in NAMES for n in names)):
            out.append(f"line {line}: {', '.join(names) or 'import delaycomp'}")
    return out


@pytest.mark.parametrize("module,path,is_package", CASES, ids=[m for m, _, _ in CASES])
def test_nothing_below_the_face_imports_the_package_face(module, path, is_package):
    """The version lives in a leaf (``delaycomp.version``): only the face (the API, the
    command line) imports ``delaycomp`` itself."""
    if unit(module) == ("face", 8) or module == "delaycomp":
        return
    assert face_imports(module, path, is_package) == [], module


def test_a_face_import_is_found(tmp_path):
    """The check finds what it is for (a check that could not fail would prove nothing)."""
    bad = tmp_path / "m.py"
    bad.write_text("import delaycomp\nfrom delaycomp import __version__, progress\n"
                   "from delaycomp import errors\n")
    assert face_imports("delaycomp.maths.m", bad, False) == [
        "line 1: import delaycomp", "line 2: __version__, progress"]


def _rings(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_ring_of_modules():
    assert _rings(EDGES) == []


def test_a_ring_is_found():
    """The ring finder finds rings (a check that could not fail would prove nothing)."""
    assert _rings({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _rings({"a": {"b"}, "b": set()}) == []


def floors() -> dict[str, int]:
    """Each unit's floor measured from the imports: 1 + the highest unit it imports."""
    graph: dict[str, set[str]] = {}
    for module, targets in EDGES.items():
        u = unit(module)[0]
        graph.setdefault(u, set()).update(unit(t)[0] for t in targets if unit(t)[0] != u)
    memo: dict[str, int] = {}

    def floor(u: str, seen: tuple[str, ...] = ()) -> int:
        assert u not in seen, f"units in a ring: {[*seen, u]}"
        if u not in memo:
            memo[u] = 1 + max((floor(v, (*seen, u)) for v in graph[u]), default=0)
        return memo[u]

    return {u: floor(u) for u in sorted(graph)}


def test_floors_of_the_units():
    measured = floors()
    by_floor: dict[int, list[str]] = {}
    for u, f in measured.items():
        by_floor.setdefault(f, []).append(u)
    for f in sorted(by_floor, reverse=True):
        print(f"floor {f}: {', '.join(by_floor[f])}")
    assert max(measured.values()) <= MAX_FLOORS
    declared = dict(UNITS.values())
    assert all(measured[u] <= declared[u] for u in measured), (measured, declared)


def _private_uses(module: str, path: Path, is_package: bool):
    """Private names of other modules of ours that ``module`` takes: imported by name, or
    read as an attribute of a module of ours it imported."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    aliases: dict[str, str] = {}
    for target, names, line in imports(module, path, is_package):
        if not target.startswith("delaycomp"):
            continue
        for name in names:
            if name.startswith("_") and not name.startswith("__") and target != module:
                yield f"{target}.{name} (line {line})"
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            for a in node.names:
                full = f"{node.module}.{a.name}" if node.module and not node.level else None
                if full in NAMES and full != module:
                    aliases[a.asname or a.name] = full
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.asname and a.name in NAMES:
                    aliases[a.asname] = a.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and node.attr.startswith("_")
                and not node.attr.startswith("__")):
            yield f"{aliases[node.value.id]}.{node.attr} (line {node.lineno})"


@pytest.mark.parametrize("module,path,is_package", CASES, ids=[m for m, _, _ in CASES])
def test_no_private_name_across_modules(module, path, is_package):
    taken = sorted(set(_private_uses(module, path, is_package)))
    assert not taken, f"{module} takes private names of other modules: {taken}"


def test_reference_shares_no_code_with_delaycomp():
    """The reference computations stay independent of what they check."""
    ref = [m for m in EDGES if unit(m)[0] == "reference"]
    assert ref
    assert {t for m in ref for t in EDGES[m]} <= set(ref)


# -- a checkout as it installs (delaycomp.layout) ------------------------------------------

@pytest.mark.parametrize("old", ["delaycomp.lti", "delaycomp.simulate",
                                 "delaycomp.models.unicycle", "delaycomp.fmuslave"])
def test_the_names_before_the_layers_are_gone(old):
    """The modules' names before the layers became folders import no more (they had no
    user left): only the names where the modules are."""
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)


def test_a_name_that_never_existed_is_still_refused():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("delaycomp.no_such_module")


def test_the_checkout_imports_as_it_installs(tmp_path):
    """From a checkout that is not installed (no site initialization, so no editable
    install's finder; only the checkout and the dependencies on the path), the folders
    beside ``delaycomp/`` are its subpackages, as in the wheel."""
    import numpy

    deps = str(Path(numpy.__file__).resolve().parent.parent)
    code = ("import sys, delaycomp.orchestrator.master as m, delaycomp.fmus, "
            "delaycomp.reference; from delaycomp.fmu.build import FMU_ROOT; "
            "assert not any('editable' in type(f).__module__ for f in sys.meta_path); "
            "print(m.__file__); print(FMU_ROOT)")
    env = {"PYTHONPATH": os.pathsep.join([str(REPO), deps]), "PATH": os.environ["PATH"]}
    out = subprocess.run([sys.executable, "-S", "-c", code], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(REPO / "orchestrator" / "master.py"), str(REPO / "fmus")]


@pytest.mark.fmu
@pytest.mark.parametrize("rootdir_on_path", [True, False], ids=["checkout-on-path",
                                                                 "editable-finder-only"])
def test_a_process_that_starts_from_an_fmus_path_finds_the_whole_package(
        fmu_dir, tmp_path, rootdir_on_path):
    """A Python FMU's binary puts its resources folder (with the part of delaycomp it
    bundles) first on ``sys.path``; a process started from there (a sweep's worker, a Dask
    worker) copies that path. It takes the FMU's own modules from the bundle and finds the
    rest of the package (``paper.scenarios``, ``studies``) where it is installed: on the
    path, or through an editable install's finder (``delaycomp.layout.whole``)."""
    import zipfile

    with zipfile.ZipFile(fmu_dir / "DelaycompDelay.fmu") as zf:
        zf.extractall(tmp_path / "fmu")
    resources = tmp_path / "fmu" / "resources"
    path = [str(resources), *([str(REPO)] if rootdir_on_path else [])]
    code = (f"import sys; sys.path[:0] = {path!r}\n"
            "import delaycomp.maths.grid as g, delaycomp.paper.scenarios as s, "
            "delaycomp.studies.sweep as w, delaycomp.fmu.build as b\n"
            "print(g.__file__); print(s.__file__); print(w.__file__); print(b.__file__)")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    grid, scenarios, sweep, build = map(Path, out.stdout.split())
    assert grid.is_relative_to(resources)  # the FMU's own maths first
    for module in (scenarios, sweep, build):
        assert module.is_relative_to(REPO / "delaycomp"), module


# -- the C of the native FMUs (item 5): one FMU, one folder; the FMI layer knows no model --
FMUS_DIR = REPO / "fmus"
SHARED_C = FMUS_DIR / "native"


def _c_code(path: Path) -> str:
    """A C file without its comments and string literals (what the compiler reads as
    names)."""
    import re

    text = path.read_text(encoding="utf-8")
    return re.sub(r'/\*.*?\*/|//[^\n]*|"(?:\\.|[^"\\])*"', " ", text, flags=re.S)


def _c_files() -> list[Path]:
    return sorted(p for p in FMUS_DIR.rglob("*.[ch]") if "host" not in p.parts)


def c_edges() -> dict[str, set[str]]:
    """File -> the files whose external functions it calls (a function defined in
    several files, each model's ``model_*``, points to each)."""
    import re

    sources = [p for p in _c_files() if p.suffix == ".c"]
    defines = {str(p.relative_to(REPO)): set(re.findall(
        r"^[A-Za-z_][\w \t\*]*?\b(\w+)\s*\([^;{]*\)\s*\{", _c_code(p), flags=re.M))
        for p in sources}  # every function a file defines, static or not
    external = {str(p.relative_to(REPO)): set(re.findall(
        r"^(?!static\b)[A-Za-z_][\w \t\*]*?\b(\w+)\s*\([^;{]*\)\s*\{", _c_code(p),
        flags=re.M)) for p in sources}
    graph: dict[str, set[str]] = {}
    for path in sources:
        me = str(path.relative_to(REPO))
        called = set(re.findall(r"\b(\w+)\s*\(", _c_code(path))) - defines[me]
        graph[me] = {f for f, names in external.items() if f != me and called & names}
    return graph


def test_no_ring_of_c_files():
    """The FMI layers call their core; the core calls the model; the model calls the shared
    helpers (native.c, pyrepr.c, linalg.c, ode.c, model_common.c); none calls back up."""
    graph = c_edges()
    assert graph["fmus/native/fmi2.c"] >= {"fmus/native/core.c", "fmus/native/native.c"}
    assert graph["fmus/native/core.c"] >= {"fmus/delay/delay.c", "fmus/native/native.c"}
    assert _rings(graph) == []


def test_the_fmi_layer_knows_no_model():
    """The shared C names no model: no per-kind switch, no model's file, data or value
    reference; each model's ModelData comes from its own header (MODEL_HEADER)."""
    import re

    from delaycomp.fmu.build import FMUS

    models = {spec.native for spec in FMUS.values() if spec.native}
    for path in sorted(SHARED_C.glob("*.[ch]")):
        code = _c_code(path)
        assert "KIND_" not in code, path
        assert not models & set(re.findall(r"\w+", code)), path
        assert not re.search(r"\bVR_\w+", code), path  # value references: the model's


def test_each_native_model_lives_beside_its_python_twin():
    """``fmus/<kind>/<name>.c``, ``.h`` and ``.toml`` beside the Python FMU; nothing of a
    model in ``fmus/native/``; the Python-repr formatting in its own file."""
    from delaycomp.fmu.build import FMUS
    from delaycomp.fmu.native import MODEL_KINDS, NATIVE_KINDS, native_twin

    assert set(NATIVE_KINDS) | set(MODEL_KINDS) == {k for k, s in FMUS.items() if s.native}
    for kind in (*NATIVE_KINDS, *MODEL_KINDS):
        twin = native_twin(kind)
        assert twin.folder == FMUS[kind].script_path.parent
        assert all(f.is_file() for f in twin.files), twin.files
        assert all((SHARED_C / u).is_file() for u in twin.uses)
        assert "model_setup" in _c_code(twin.files[0])
    assert not [p for p in SHARED_C.glob("*.c") if "model_setup(Instance" in _c_code(p)
                and p.name != "fmi2.c"]
    assert "Num num(double v)" in (SHARED_C / "pyrepr.c").read_text(encoding="utf-8")
    assert '#include "native.h"' not in (SHARED_C / "pyrepr.c").read_text(encoding="utf-8")


def test_the_grid_and_held_sample_rules_are_written_once_in_c():
    """The rule whether a value is a whole number of a step (delaycomp.maths.grid's
    ``nearest_multiple``: within GRID_RTOL of ``max(1, |ratio|)``) is written once in C,
    ``fmus/native/grid.c``, and so are the controllers' held sample and proposal
    (``HeldSampleMixin``), ``held.c``: the delay, the channel and the controllers call
    them, so no copy can drift from the Python rule on its own."""
    import re

    def literals(path: Path) -> str:
        return " ".join(re.findall(r'"((?:\\.|[^"\\])*)"', path.read_text(encoding="utf-8")))

    def where(pattern: str, text=_c_code) -> set[str]:
        return {p.name for p in _c_files() if re.search(pattern, text(p))}

    assert where(r"GRID_RTOL\s*\*\s*fmax\(\s*1\.0\b") == {"grid.c"}
    for rule in ("nearest_multiple", "steps_up", "split", "padded_delay"):  # defined once
        # (fates.c, the batch's kernel outside any FMU, has channel_batch.steps_up: numpy's)
        assert where(rf"(?m)^[A-Za-z_][\w \t*]*\b{rule}\s*\([^;{{]*\)\s*\{{") - {
            "fates.c"} == {"grid.c"}
    assert where(r"y_held_valid\s*\?\s*[\w>.-]*y_held\b") == {"held.c"}  # the sample read
    assert where(r"memcpy\(\s*[\w>.-]*y_held\b") == {"held.c"}  # the sample held
    assert where(r"must be 0 with held_sample = false", literals) == {"held.c"}
    assert where(r"u_i of the current sample", literals) == {"held.c"}


# -- errors (item 2): one class per name, every one a DelaycompError --------------------
def _error_classes() -> dict[str, list[tuple[str, list[str]]]]:
    """Every class of the package that is an exception, by name: ``[(module, bases)]``
    (bases as written, the last part of a dotted name)."""
    import builtins

    classes: dict[str, list[tuple[str, list[str]]]] = {}
    for module, path, _ in CASES:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                bases = [b.id if isinstance(b, ast.Name) else b.attr
                         for b in node.bases if isinstance(b, (ast.Name, ast.Attribute))]
                classes.setdefault(node.name, []).append((module, bases))

    def is_error(name: str, seen=()) -> bool:
        builtin = getattr(builtins, name, None)
        if isinstance(builtin, type) and issubclass(builtin, BaseException):
            return True
        return name not in seen and any(is_error(b, (*seen, name))
                                        for _, bases in classes.get(name, ())
                                        for b in bases)

    return {name: defs for name, defs in classes.items() if is_error(name)}


def test_each_class_name_is_one_class():
    """No two classes of the package share a name (one ``Timing``, the loop's base grid;
    one ``Connection``, the loop's and the master's; one ``ParameterError``)."""
    where: dict[str, list[str]] = {}
    for module, path, _ in CASES:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                where.setdefault(node.name, []).append(module)
    assert {name: mods for name, mods in where.items() if len(mods) > 1} == {}


def test_every_error_is_a_delaycomp_error_and_each_name_is_one_class():
    """One ``ParameterError`` (and one of every error name); each error class derives
    from ``delaycomp.errors.DelaycompError``, so a caller catches them all with it."""
    errors = _error_classes()
    assert "ParameterError" in errors and "SimulationError" in errors
    twice = {name: [m for m, _ in defs] for name, defs in errors.items() if len(defs) > 1}
    assert twice == {}

    def derives(name: str) -> bool:  # an interrupt (KeyboardInterrupt's kin) is no error
        return name in ("DelaycompError", "KeyboardInterrupt") or any(
            derives(b) for _, bases in errors.get(name, ()) for b in bases)

    assert [name for name in errors if not derives(name)] == []


# -- public names documented (item 4) ----------------------------------------------------
#: the paper's model files are in the model-file format of docs/reference/model-files.md,
#: and their text names their FMUs (a digest): they document themselves in their module docstrings
UNDOCUMENTED_OK = ("delaycomp.paper.models.",)


def test_public_names_have_a_docstring():
    """Every public function and class of the package, and every public method of a
    public class, has a docstring (what ``help()`` and the API pages show)."""
    missing = []
    for module, path, _ in CASES:
        if module.startswith(UNDOCUMENTED_OK):
            continue
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) \
                    or node.name.startswith("_"):
                continue
            if ast.get_docstring(node) is None:
                missing.append(f"{module}.{node.name}")
            if isinstance(node, ast.ClassDef):
                missing += [f"{module}.{node.name}.{sub.name}" for sub in node.body
                            if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef))
                            and not sub.name.startswith("_") and ast.get_docstring(sub) is None]
    assert missing == []
