"""Build the project's FMUs with pythonfmu, each in its own Python process.

One registry (``FMUS``) drives the build and the tests. Every FMU bundles the slave
module, the subset of ``delaycomp`` it imports, and ``delaycomp_fmu.json`` (its
dimensions and the package version). ``probe_instantiation`` reports what a built
FMU imports when a host instantiates it, and how long that takes.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

from delaycomp.child import module_argv
from delaycomp.fmu.runtime import is_runtime, patch_runtime
from delaycomp.maths.model import model_id
from delaycomp.names import CONFIG_NAME
from delaycomp.tmpfiles import temp_dir
from delaycomp.version import __version__


def _fmus_folder() -> Path:
    """The FMUs' folder (``fmus/`` in the repository, installed as ``delaycomp.fmus``).
    The build reads it as data (slave modules to bundle, C sources to compile) and never
    imports it: the FMUs stand above their build."""
    spec = importlib.util.find_spec("delaycomp.fmus")
    assert spec is not None and spec.origin is not None
    return Path(spec.origin).resolve().parent


#: The slave modules and C sources (``fmus/`` in the repository, ``delaycomp.fmus``).
FMU_ROOT = _fmus_folder()
PACKAGE_DIR = Path(__file__).resolve().parent.parent

#: Modules of ``delaycomp`` that run inside the FMUs (no CLI, no plotting, no fmpy): the
#: package's light base, the maths (``delaycomp.maths``), the base slave
#: (``delaycomp.fmu.slave``, ``.statehandle``) and the sampled controllers' part
#: (``delaycomp.fmu.sampling``). The paper's models (``paper/models/*.py``) are bundled too:
#: their modules import each other. The packages' ``__init__.py`` import nothing.
BUNDLED_MODULES = ("__init__.py", "version.py", "errors.py", "names.py", "layout.py",
                   "fmu/__init__.py",
                   "fmu/slave.py", "fmu/statehandle.py", "fmu/sampling.py",
                   "paper/__init__.py",
                   *sorted(f"maths/{p.name}" for p in (PACKAGE_DIR / "maths").glob("*.py")),
                   *sorted(f"paper/models/{p.name}"
                           for p in (PACKAGE_DIR / "paper" / "models").glob("*.py")))


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the registry: its folder under ``fmus/``, slave module and identifier.

    For a model template (``template=True``) the slave module defines a base class; the
    build generates a subclass for one model, named ``<model_identifier>_<model id>``.
    """

    kind: str
    script: str
    model_identifier: str
    #: pythonfmu model options (canHandleVariableCommunicationStepSize, ...)
    options: tuple[tuple[str, bool], ...] = ()
    template: str = ""  # base class name in ``script`` for model templates
    #: the native twin in the same folder (``delaycomp.fmu.native``): ``<native>.c``,
    #: its data in ``<native>.h``, its manifest ``<native>.toml``; "" where there is none
    native: str = ""
    #: the model ``CONTROL``s a model template takes (``delaycomp.maths.model.CONTROLS``;
    #: empty: any)
    controls: tuple[str, ...] = ()

    @property
    def folder(self) -> Path:
        """The FMU's folder, ``fmus/<kind>`` (under ``FMU_ROOT``)."""
        return FMU_ROOT / self.kind

    @property
    def script_path(self) -> Path:
        """The slave module's file in ``folder``."""
        return self.folder / self.script


#: Every FMU saves and restores its complete state, hidden buffers included
#: (``delaycomp.fmu.slave``, point 6), and serializes it.
_STATE = (("canGetAndSetFMUstate", True), ("canSerializeFMUstate", True))
#: The delay and the controllers run on a fixed communication step.
_FIXED_STEP = (("canHandleVariableCommunicationStepSize", False),)

FMUS: dict[str, FmuSpec] = {
    "plant": FmuSpec("plant", "delaycomp_plant_lti.py", "DelaycompPlantLTI", _STATE,
                     native="plant_lti"),
    "delay": FmuSpec("delay", "delaycomp_delay.py", "DelaycompDelay", _FIXED_STEP + _STATE,
                     native="delay"),
    # a network channel in a delay's place; its folder is the delay's
    "channel": FmuSpec("delay", "delaycomp_channel.py", "DelaycompChannel",
                       _FIXED_STEP + _STATE, native="channel"),
    "controller": FmuSpec("controller", "delaycomp_controller_lti.py",
                          "DelaycompControllerLTI", _FIXED_STEP + _STATE,
                          native="controller_lti"),
    # the time-stamp controller of an LTI plant
    "stamped_controller": FmuSpec("controller", "delaycomp_controller_stamped.py",
                                  "DelaycompControllerStamped", _FIXED_STEP + _STATE,
                                  native="controller_stamped"),
    "model_plant": FmuSpec("plant", "delaycomp_model_plant.py", "DelaycompPlant", _STATE,
                           template="ModelPlantSlave", native="model_plant"),
    "model_controller": FmuSpec("controller", "delaycomp_model_controller.py",
                                "DelaycompController", _FIXED_STEP + _STATE,
                                template="ModelControllerSlave", native="model_controller"),
    # the time-stamp controller of a model plant under zero-order hold
    "stamped_model_controller": FmuSpec("controller", "delaycomp_model_controller_stamped.py",
                                        "DelaycompControllerStamped", _FIXED_STEP + _STATE,
                                        template="StampedModelControllerSlave",
                                        controls=("zoh",)),
}

#: Dimensions of the default build: the scalar loop of Example 3.6.
DEFAULT_CONFIG: dict[str, dict[str, Any]] = {
    "plant": {"n": 1, "m": 1, "state": "x", "input": "u"}, "delay": {"n": 1},
    "channel": {"n": 1}, "controller": {"n": 1, "m": 1},
    "stamped_controller": {"n": 1, "m": 1}}

#: the longest delay trace a channel FMU is built for (config ``L``: ``trace[1..L]``)
TRACE_MAX = 10_000

#: the LTI loop's FMUs, which ``build_all`` builds
LOOP_KINDS = ("plant", "delay", "controller")


def model_identifier(kind: str, config: dict) -> str:
    """The FMU's modelIdentifier (and class name) for ``kind`` and ``config``."""
    spec = FMUS[kind]
    if spec.template:
        return f"{spec.model_identifier}_{model_id(config['model'])}"
    return spec.model_identifier


def check_model_control(kind: str, model_path) -> None:
    """``ParameterError`` (one line) where the model file's ``CONTROL`` is not one the
    template ``kind`` takes (``FmuSpec.controls``): the time-stamp controller holds
    ``k(x, p)`` over each period, so it takes ``CONTROL = "zoh"`` only."""
    controls = FMUS[kind].controls
    if not controls:
        return
    from delaycomp.errors import ParameterError
    from delaycomp.maths.model import load_model

    model = load_model(model_path)
    if model.control not in controls:
        raise ParameterError(f"model = {model.name!r} is not allowed for the {kind} FMU: its "
                             f"CONTROL is {model.control!r}; must be "
                             f"{' or '.join(repr(c) for c in controls)}")


def check_dimensions(config: dict) -> None:
    """``ValueError`` naming a build's dimension out of its range: ``n``, ``m`` 1 to 1000,
    the channel's trace length ``L`` 0 to ``TRACE_MAX``."""
    for key in ("n", "m"):
        if key in config and not (type(config[key]) is int and 1 <= config[key] <= 1000):
            raise ValueError(f"{key} = {config[key]!r} is not allowed: must be an integer "
                             "from 1 to 1000 (a dimension of the FMU)")
    if "L" in config and not (type(config["L"]) is int and 0 <= config["L"] <= TRACE_MAX):
        raise ValueError(f"L = {config['L']!r} is not allowed: must be an integer from 0 to "
                         f"{TRACE_MAX} (the length of the channel's delay trace)")


def source_digest() -> str:
    """Digest of everything that goes into a Python FMU: it names the build cache, and
    each Python FMU records it as ``sources`` in its build configuration."""
    h = hashlib.sha256(__version__.encode())
    # the fix of pythonfmu's runtime library (delaycomp.fmu.runtime) goes into every FMU too
    files = [PACKAGE_DIR / m for m in BUNDLED_MODULES] + [PACKAGE_DIR / "fmu" / "runtime.py"]
    for spec in FMUS.values():
        files += [spec.script_path, spec.folder / "README.md"]
    for f in files:
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def build_fmu(kind: str, out_dir: Path, config: dict | None = None,
              file_name: str | None = None) -> Path:
    """Build the FMU ``kind`` of ``FMUS`` into ``out_dir``; return the ``.fmu`` path.

    The build runs in a fresh Python process, so a module loaded by an earlier build in
    this process can never leak into the FMU.
    """
    spec = FMUS[kind]
    if config is None:
        config = dict(DEFAULT_CONFIG[kind])
    config = dict(config)
    check_dimensions(config)
    if spec.template:
        check_model_control(kind, config["model"])
    config["version"] = __version__

    # what a run checks an FMU of --fmu-dir against (the cache's folders are named by it)
    config["sources"] = source_digest()
    ident = model_identifier(kind, config)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / (file_name or f"{ident}.fmu")
    from delaycomp.progress import detail

    detail(f"building {ident} (Python, pythonfmu) into {out_dir} ...")
    # pythonfmu writes into a folder of ours; the finished file is renamed into place:
    # a reader never sees a half-written FMU, and a link at the target is replaced, never
    # written through
    with temp_dir("delaycomp-build-") as tmp:
        tmp_path = Path(tmp)
        script, project = _stage_project(spec, tmp_path, config, ident)
        doc = tmp_path / "documentation"
        doc.mkdir()
        shutil.copy2(spec.folder / "README.md", doc / "README.md")
        built = _run_pythonfmu(kind, spec, tmp_path, script, project, doc, target.name)
        _finish(built, config.get("start") or {})
        publish(built, target)
    return target


def _stage_project(spec: FmuSpec, tmp_path: Path, config: dict,
                   ident: str) -> tuple[Path, list[Path]]:
    """Write the FMU's project files under ``tmp_path``: the bundled delaycomp modules, for a
    model template the model and a generated subclass, and the build configuration
    (``config``, whose ``model`` becomes ``model_name`` and ``model_id``); the slave script
    and the project files."""
    pkg = tmp_path / "delaycomp"
    for name in BUNDLED_MODULES:
        (pkg / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(PACKAGE_DIR / name, pkg / name)
    project = [pkg]
    script = spec.script_path
    if spec.template:
        model_path = Path(config.pop("model")).resolve()
        mid = model_id(model_path)
        config["model_name"] = model_path.stem
        config["model_id"] = mid
        model_module = f"delaycomp_model_{mid}"
        shutil.copy2(model_path, tmp_path / f"{model_module}.py")
        shutil.copy2(spec.script_path, tmp_path / spec.script_path.name)
        # named after the template's own module: unique per registry kind (pythonfmu FMUs
        # share one interpreter's sys.modules, so two templates of one model must differ)
        script = tmp_path / f"{spec.script_path.stem}_{mid}.py"
        script.write_text(
            f'"""{spec.kind} FMU of model {model_path.stem} (generated by delaycomp '
            f'build)."""\n\nfrom {spec.script_path.stem} import {spec.template}\n\n\n'
            f"class {ident}({spec.template}):\n"
            f"    model_module = {model_module!r}\n\n\n"
            f"# see delaycomp.fmu.slave._PINNED_MODULE_DICTS\n"
            f"_PIN = [globals()]\n", encoding="utf-8")
        project += [tmp_path / f"{model_module}.py", tmp_path / spec.script_path.name]
    cfg = tmp_path / CONFIG_NAME
    cfg.write_text(json.dumps(config, sort_keys=True), encoding="utf-8")
    project.append(cfg)
    return script, project


def _run_pythonfmu(kind: str, spec: FmuSpec, tmp_path: Path, script: Path,
                   project: list[Path], doc: Path, name: str) -> Path:
    """Run pythonfmu's build in a fresh Python process; the FMU it wrote (``name``)."""
    staged = tmp_path / "out"
    staged.mkdir()
    request = {
        "script": str(script),
        "dest": str(staged / name),
        "project_files": [str(p) for p in project],
        "documentation_folder": str(doc),
        "options": dict(spec.options),
    }
    proc = subprocess.run(
        module_argv("delaycomp.fmu.build", json.dumps(request)),
        cwd=tmp_path, capture_output=True, text=True,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"building the {kind} FMU failed:\n{proc.stderr.strip()}")
    built = staged / name
    if not built.is_file():
        raise RuntimeError(f"building the {kind} FMU failed: pythonfmu wrote no "
                           f"{name}")
    return built


def start_text(typ: str, value) -> str:
    """A start value as a modelDescription should hold it: a Real as ``repr`` (the
    shortest text that reads back as the same double; pythonfmu writes 16 significant
    digits, which may not), a Boolean as ``true``/``false``, an Integer, a String as it
    is.

    >>> start_text("Real", -11 / 6), start_text("Boolean", True), start_text("Integer", 3)
    ('-1.8333333333333333', 'true', '3')
    """
    if typ == "Real":
        return repr(float(value))
    if typ == "Boolean":
        return "true" if value else "false"
    if typ == "Integer":
        return str(int(value))
    return str(value)


def set_start(xml: str, name: str, value,
              fmt: Callable[[str, object], str] = start_text) -> str:
    """``xml`` (a modelDescription's text) with the start value of variable ``name`` set
    to ``value``, written by ``fmt(type, value)``; the rest of the text as it was.
    Raises ``ValueError`` for a name that is no variable with a start value."""
    pattern = re.compile(r'(<ScalarVariable name="' + re.escape(escape(name, {'"': "&quot;"}))
                         + r'"[^>]*>\s*<(Real|Integer|Boolean|String) start=")([^"]*)(")')
    match = pattern.search(xml)
    if match is None:
        raise ValueError(f"no parameter {name!r} with a start value in the modelDescription")
    text = escape(fmt(match.group(2), value), {'"': "&quot;"})
    return xml[:match.start(3)] + text + xml[match.end(3):]


def _finish(fmu: Path, start: Mapping) -> None:
    """Rewrite the pythonfmu FMU ``fmu`` as we ship it: its linux64 runtime library with
    the fix of ``delaycomp.fmu.runtime`` (a heap corruption at exit), and, for a build
    with a ``start`` table, a modelDescription whose start values read back as the very
    values the slave holds (``start_text``)."""
    part = fmu.with_name(fmu.name + ".finished")
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            data = zin.read(info)
            if info.filename == "modelDescription.xml" and start:
                xml = data.decode("utf-8")
                for name, value in start.items():
                    xml = set_start(xml, name, value)
                data = xml.encode("utf-8")
            elif is_runtime(info.filename):
                data = patch_runtime(data)
            zout.writestr(info, data)
    os.replace(part, fmu)


def publish(built: Path, target: Path) -> None:
    """Move ``built`` to ``target`` atomically (same file system: a copy beside the target
    first, then a rename over it)."""
    part = target.parent / f".{target.name}.{os.getpid()}.part"
    if part.is_symlink() or part.exists():
        part.unlink()
    try:
        shutil.copyfile(built, part)
        os.replace(part, target)
    finally:
        if part.exists():
            part.unlink()


def build_model(model_path: str | Path, out_dir: Path) -> list[Path]:
    """Plant and controller FMUs for a model file, and delay FMUs of matching widths."""
    from delaycomp.maths.model import load_model

    model = load_model(model_path)  # checks the interface before any build
    paths = [build_fmu("model_plant", out_dir, {"model": str(model_path)}),
             build_fmu("model_controller", out_dir, {"model": str(model_path)})]
    for width in sorted({model.n, model.m}):
        cfg = {"n": width}
        name = None if cfg == DEFAULT_CONFIG["delay"] else f"DelaycompDelay_n{width}.fmu"
        paths.append(build_fmu("delay", out_dir, cfg, name))
    return paths


def build_all(out_dir: Path) -> list[Path]:
    """Build the LTI loop's FMUs (plant, delay, controller) with default dimensions."""
    return [build_fmu(kind, out_dir) for kind in LOOP_KINDS]


#: What ``probe_instantiation`` runs in a fresh interpreter: what pythonfmu's binary does
#: at ``fmi2Instantiate`` (the resources folder first on ``sys.path``, the module named in
#: ``slavemodule.txt`` imported, its slave class called with ``instance_name`` and
#: ``resources``), timed from before the import to the instance.
_PROBE = """
import importlib, json, sys, time
resources, module, name = sys.argv[1:4]
before = set(sys.modules)
started = time.perf_counter()
sys.path.insert(0, resources)
slave = getattr(importlib.import_module(module), name)(instance_name="probe",
                                                      resources=resources, visible=False)
seconds = time.perf_counter() - started
print(json.dumps({"seconds": seconds, "modules": sorted(set(sys.modules) - before)}))
"""


@dataclass(frozen=True)
class Instantiation:
    """What instantiating a Python FMU imported (``probe_instantiation``)."""

    #: wall time of the import of the slave module and of the instance [s]
    seconds: float
    #: every module it imported (the interpreter's own start-up modules excluded)
    modules: tuple[str, ...]

    @property
    def packages(self) -> tuple[str, ...]:
        """The installed packages among ``modules`` (top-level names; neither the
        standard library nor the FMU's own bundled modules)."""
        own = ("delaycomp", "delaycomp_")
        tops = {m.split(".")[0] for m in self.modules}
        return tuple(sorted(t for t in tops if not t.startswith(("_", *own))
                            and t not in sys.stdlib_module_names
                            and t != "cython_runtime"))  # Cython makes it, no package

    @property
    def subpackages(self) -> tuple[str, ...]:
        """``package.subpackage`` names of ``packages`` (``scipy.linalg``, ...)."""
        return tuple(sorted({".".join(m.split(".")[:2]) for m in self.modules
                             if "." in m and m.split(".")[0] in self.packages
                             and not m.split(".")[1].startswith("_")}))

    @property
    def delaycomp_modules(self) -> tuple[str, ...]:
        """The modules of the bundled ``delaycomp`` it imported."""
        return tuple(m for m in self.modules if m.startswith("delaycomp."))


def probe_instantiation(fmu: str | Path) -> Instantiation:
    """Instantiate the Python FMU ``fmu`` in a fresh interpreter, as pythonfmu's binary
    does in a host, and report what that imported and how long it took.

    A host that loads a Python FMU pays this once per process (a second instance finds the
    modules loaded). The interpreter is this one (``sys.executable``) with its installed
    packages; the FMU's bundled ``delaycomp`` comes first, as in a host.

    Raises
    ------
    RuntimeError
        The FMU is not a pythonfmu FMU, or its instantiation failed (the child's error).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     probe = probe_instantiation(build_fmu("delay", Path(tmp)))
    >>> probe.packages, "scipy" in probe.modules
    (('numpy', 'pythonfmu'), False)
    """
    from delaycomp.tmpfiles import temp_dir

    with temp_dir("delaycomp-probe-") as tmp, zipfile.ZipFile(fmu) as zf:
        zf.extractall(tmp)
        resources = Path(tmp) / "resources"
        try:
            module = (resources / "slavemodule.txt").read_text(encoding="utf-8").strip()
        except OSError:
            raise RuntimeError(f"{fmu} is not a pythonfmu FMU (no "
                               "resources/slavemodule.txt)") from None
        import xml.etree.ElementTree as ET

        cs = ET.parse(Path(tmp) / "modelDescription.xml").getroot().find("CoSimulation")
        name = cs.get("modelIdentifier") if cs is not None else None
        proc = subprocess.run([sys.executable, "-c", _PROBE, str(resources), module,
                               str(name)], cwd=tmp, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"instantiating {Path(fmu).name} failed:\n{proc.stderr.strip()}")
    res = json.loads(proc.stdout)
    return Instantiation(res["seconds"], tuple(res["modules"]))


def _build_in_this_process(request: dict) -> None:
    from pythonfmu.builder import FmuBuilder

    FmuBuilder.build_FMU(
        request["script"], dest=request["dest"], project_files=request["project_files"],
        documentation_folder=request["documentation_folder"], **request["options"],
    )


if __name__ == "__main__":  # the per-FMU build process
    _build_in_this_process(json.loads(sys.argv[1]))
