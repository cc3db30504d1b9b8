"""Build the project's FMUs with pythonfmu, each in its own Python process.

One registry (:data:`FMUS`) drives the build and the tests. Every FMU bundles the slave
module, the subset of :mod:`delaycomp` it imports, and ``delaycomp_fmu.json`` (its
dimensions and the package version).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import delaycomp
CONFIG_NAME = "delaycomp_fmu.json"  # same as delaycomp.fmuslave.CONFIG_NAME

FMU_ROOT = Path(__file__).resolve().parent.parent / "fmus"
PACKAGE_DIR = Path(__file__).resolve().parent

#: Modules of :mod:`delaycomp` that run inside the FMUs (no CLI, no plotting, no fmpy).
BUNDLED_MODULES = ("__init__.py", "lti.py", "controller.py", "delayline.py", "fmuslave.py",
                    "names.py")


@dataclass(frozen=True)
class FmuSpec:
    """One FMU of the registry: its folder under ``fmus/``, slave module and identifier."""

    kind: str
    script: str
    model_identifier: str
    #: pythonfmu model options (canHandleVariableCommunicationStepSize, ...)
    options: tuple[tuple[str, bool], ...] = ()

    @property
    def folder(self) -> Path:
        return FMU_ROOT / self.kind

    @property
    def script_path(self) -> Path:
        return self.folder / self.script


FMUS: dict[str, FmuSpec] = {
    "plant": FmuSpec("plant", "delaycomp_plant_lti.py", "DelaycompPlantLTI"),
    "delay": FmuSpec("delay", "delaycomp_delay.py", "DelaycompDelay",
                     (("canHandleVariableCommunicationStepSize", False),)),
    "controller": FmuSpec("controller", "delaycomp_controller_lti.py",
                          "DelaycompControllerLTI",
                          (("canHandleVariableCommunicationStepSize", False),)),
}

#: Dimensions of the default build: the scalar loop of Example 3.6.
DEFAULT_CONFIG = {"plant": {"n": 1, "m": 1, "state": "x", "input": "u"}, "delay": {"n": 1}, "controller": {"n": 1, "m": 1}}


def build_fmu(kind: str, out_dir: Path, config: dict | None = None,
              file_name: str | None = None) -> Path:
    """Build the FMU ``kind`` of :data:`FMUS` into ``out_dir``; return the ``.fmu`` path.

    The build runs in a fresh Python process, so a module loaded by an earlier build in
    this process can never leak into the FMU.
    """
    spec = FMUS[kind]
    config = dict(DEFAULT_CONFIG[kind] if config is None else config)
    config["version"] = delaycomp.__version__
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / (file_name or f"{spec.model_identifier}.fmu")
    with tempfile.TemporaryDirectory(prefix="delaycomp-build-") as tmp:
        tmp_path = Path(tmp)
        pkg = tmp_path / "delaycomp"
        pkg.mkdir()
        for name in BUNDLED_MODULES:
            shutil.copy2(PACKAGE_DIR / name, pkg / name)
        cfg = tmp_path / CONFIG_NAME
        cfg.write_text(json.dumps(config, sort_keys=True), encoding="utf-8")
        doc = tmp_path / "documentation"
        doc.mkdir()
        shutil.copy2(spec.folder / "README.md", doc / "README.md")
        request = {
            "script": str(spec.script_path),
            "dest": str(target),
            "project_files": [str(cfg), str(pkg)],
            "documentation_folder": str(doc),
            "options": dict(spec.options),
        }
        proc = subprocess.run(
            [sys.executable, "-m", "delaycomp.build", json.dumps(request)],
            cwd=tmp, capture_output=True, text=True,
        )
        if proc.returncode != 0:
            raise RuntimeError(f"building the {kind} FMU failed:\n{proc.stderr.strip()}")
    return target


def build_all(out_dir: Path) -> list[Path]:
    """Build every FMU of the registry with its default dimensions."""
    return [build_fmu(kind, out_dir) for kind in FMUS]


def _build_in_this_process(request: dict) -> None:
    from pythonfmu.builder import FmuBuilder

    FmuBuilder.build_FMU(
        request["script"], dest=request["dest"], project_files=request["project_files"],
        documentation_folder=request["documentation_folder"], **request["options"],
    )


if __name__ == "__main__":  # the per-FMU build process
    _build_in_this_process(json.loads(sys.argv[1]))
