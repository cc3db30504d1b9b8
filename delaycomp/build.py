"""Build the project's FMUs with pythonfmu, each in its own Python process.

One registry (:data:`FMUS`) drives the build and the tests. Every FMU bundles the slave
module, the subset of :mod:`delaycomp` it imports, and ``delaycomp_fmu.json`` (its
dimensions and the package version).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import delaycomp
import delaycomp.fmus
from delaycomp.child import module_argv

CONFIG_NAME = "delaycomp_fmu.json"  # same as delaycomp.fmuslave.CONFIG_NAME

#: The slave modules (``fmus/`` in the repository, installed as :mod:`delaycomp.fmus`).
FMU_ROOT = Path(delaycomp.fmus.__file__).resolve().parent
PACKAGE_DIR = Path(__file__).resolve().parent

#: Modules of :mod:`delaycomp` that run inside the FMUs (no CLI, no plotting, no fmpy).
#: The built-in models (``models/*.py``) are bundled too: their modules import each other.
BUNDLED_MODULES = ("__init__.py", "errors.py", "grid.py", "lti.py", "controller.py",
                   "delayline.py", "fmuslave.py", "names.py", "history.py", "model.py",
                   "nlcontrol.py", "predictors.py",
                   *sorted(f"models/{p.name}" for p in (PACKAGE_DIR / "models").glob("*.py")))


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

    @property
    def folder(self) -> Path:
        return FMU_ROOT / self.kind

    @property
    def script_path(self) -> Path:
        return self.folder / self.script


#: Every FMU saves and restores its complete state, hidden buffers included
#: (``delaycomp.fmuslave``, point 6), and serializes it.
_STATE = (("canGetAndSetFMUstate", True), ("canSerializeFMUstate", True))
#: The delay and the controllers run on a fixed communication step.
_FIXED_STEP = (("canHandleVariableCommunicationStepSize", False),)

FMUS: dict[str, FmuSpec] = {
    "plant": FmuSpec("plant", "delaycomp_plant_lti.py", "DelaycompPlantLTI", _STATE),
    "delay": FmuSpec("delay", "delaycomp_delay.py", "DelaycompDelay", _FIXED_STEP + _STATE),
    "controller": FmuSpec("controller", "delaycomp_controller_lti.py",
                          "DelaycompControllerLTI", _FIXED_STEP + _STATE),
    "model_plant": FmuSpec("plant", "delaycomp_model_plant.py", "DelaycompPlant", _STATE,
                           template="ModelPlantSlave"),
    "model_controller": FmuSpec("controller", "delaycomp_model_controller.py",
                                "DelaycompController", _FIXED_STEP + _STATE,
                                template="ModelControllerSlave"),
}

#: Dimensions of the default build: the scalar loop of Example 3.6.
DEFAULT_CONFIG = {"plant": {"n": 1, "m": 1, "state": "x", "input": "u"}, "delay": {"n": 1},
                  "controller": {"n": 1, "m": 1}}


def model_id(model_path: str | Path) -> str:
    """Identifier of a model file: its name and a digest of its content and our version."""
    path = Path(model_path)
    digest = hashlib.sha256(path.read_bytes() + delaycomp.__version__.encode()).hexdigest()
    return f"{re.sub(r'[^A-Za-z0-9_]', '_', path.stem)}_{digest[:8]}"


def model_identifier(kind: str, config: dict) -> str:
    """The FMU's modelIdentifier (and class name) for ``kind`` and ``config``."""
    spec = FMUS[kind]
    if spec.template:
        return f"{spec.model_identifier}_{model_id(config['model'])}"
    return spec.model_identifier


def build_fmu(kind: str, out_dir: Path, config: dict | None = None,
              file_name: str | None = None) -> Path:
    """Build the FMU ``kind`` of :data:`FMUS` into ``out_dir``; return the ``.fmu`` path.

    The build runs in a fresh Python process, so a module loaded by an earlier build in
    this process can never leak into the FMU.
    """
    spec = FMUS[kind]
    if config is None:
        config = dict(DEFAULT_CONFIG[kind])
    config = dict(config)
    for key in ("n", "m"):
        if key in config and not (type(config[key]) is int and 1 <= config[key] <= 1000):
            raise ValueError(f"{key} = {config[key]!r} is not allowed: must be an integer "
                             "from 1 to 1000 (a dimension of the FMU)")
    config["version"] = delaycomp.__version__
    ident = model_identifier(kind, config)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / (file_name or f"{ident}.fmu")
    with tempfile.TemporaryDirectory(prefix="delaycomp-build-") as tmp:
        tmp_path = Path(tmp)
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
            script = tmp_path / f"delaycomp_{spec.kind}_{mid}.py"
            script.write_text(
                f'"""{spec.kind} FMU of model {model_path.stem} (generated by delaycomp '
                f'build)."""\n\nfrom {spec.script_path.stem} import {spec.template}\n\n\n'
                f"class {ident}({spec.template}):\n"
                f"    model_module = {model_module!r}\n\n\n"
                f"# see delaycomp.fmuslave._PINNED_MODULE_DICTS\n"
                f"_PIN = [globals()]\n", encoding="utf-8")
            project += [tmp_path / f"{model_module}.py", tmp_path / spec.script_path.name]
        cfg = tmp_path / CONFIG_NAME
        cfg.write_text(json.dumps(config, sort_keys=True), encoding="utf-8")
        project.append(cfg)
        doc = tmp_path / "documentation"
        doc.mkdir()
        shutil.copy2(spec.folder / "README.md", doc / "README.md")
        request = {
            "script": str(script),
            "dest": str(target),
            "project_files": [str(p) for p in project],
            "documentation_folder": str(doc),
            "options": dict(spec.options),
        }
        proc = subprocess.run(
            module_argv("delaycomp.build", json.dumps(request)),
            cwd=tmp, capture_output=True, text=True,
        )
        if proc.returncode != 0:
            raise RuntimeError(f"building the {kind} FMU failed:\n{proc.stderr.strip()}")
    return target


def build_model(model_path: str | Path, out_dir: Path) -> list[Path]:
    """Plant and controller FMUs for a model file, and delay FMUs of matching widths."""
    from .model import load_model

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
    return [build_fmu(kind, out_dir) for kind, spec in FMUS.items() if not spec.template]


def _build_in_this_process(request: dict) -> None:
    from pythonfmu.builder import FmuBuilder

    FmuBuilder.build_FMU(
        request["script"], dest=request["dest"], project_files=request["project_files"],
        documentation_folder=request["documentation_folder"], **request["options"],
    )


if __name__ == "__main__":  # the per-FMU build process
    _build_in_this_process(json.loads(sys.argv[1]))
