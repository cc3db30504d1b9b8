"""Layers, imports only downward (DESIGN.md): maths < system model < FMU adapters and
masters < studies < verification < CLI and API. Each module's imports, module-level or
inside functions, are read from its source (ast) and must not point to a higher layer."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

#: the layer of each module (by installed name); a package's modules take its entry
LAYERS = {
    # 0: maths (numpy/scipy, no FMI), the grid and the model interface
    "delaycomp": 0, "delaycomp.errors": 0, "delaycomp.grid": 0, "delaycomp.names": 0,
    "delaycomp.lti": 0, "delaycomp.delayline": 0, "delaycomp.history": 0,
    "delaycomp.predictors": 0, "delaycomp.controller": 0, "delaycomp.nlcontrol": 0,
    "delaycomp.model": 0, "delaycomp.models": 0, "delaycomp.child": 0,
    "delaycomp.reference": 0, "delaycomp.batch": 0,
    # 1: the system model and the scenarios (data that build it)
    "delaycomp.system": 1, "delaycomp.scenarios": 1,
    # 2: FMU adapters, builds, masters, formats
    "delaycomp.fmuslave": 2, "delaycomp.fmus": 2, "delaycomp.build": 2,
    "delaycomp.orchestrator": 2, "delaycomp.simulate": 2, "delaycomp.ssp": 2,
    "delaycomp.native": 2, "delaycomp.loopbuild": 2, "delaycomp.exportc": 2,
    "delaycomp.plotting": 2, "delaycomp.outputs": 2, "delaycomp.progress": 2,
    # 3: studies
    "delaycomp.sweep": 3, "delaycomp.critical": 3, "delaycomp.sweep_batch": 3,
    # 4: verification
    "delaycomp.cases": 4, "delaycomp.check": 4, "delaycomp.crosscheck": 4,
    "delaycomp.container": 4, "delaycomp.thirdparty": 4, "delaycomp.omsimulator": 4,
    # 5: the faces
    "delaycomp.cli": 5, "delaycomp.api": 5, "delaycomp.__main__": 5,
}
ROOTS = {"delaycomp": REPO / "delaycomp", "delaycomp.orchestrator": REPO / "orchestrator",
         "delaycomp.fmus": REPO / "fmus"}


def layer(module: str) -> int | None:
    parts = module.split(".")
    for i in range(len(parts), 0, -1):
        if ".".join(parts[:i]) in LAYERS:
            return LAYERS[".".join(parts[:i])]
    return None


def modules():
    for prefix, root in ROOTS.items():
        for path in sorted(root.rglob("*.py")):
            rel = path.relative_to(root).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            if prefix == "delaycomp" and parts and parts[0] in ("loops",):
                continue
            yield ".".join([prefix, *parts]), path, path.name == "__init__.py"


def imports(module: str, path: Path, is_package: bool):
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            yield target
            for a in node.names:  # from . import x: x may be a module
                yield f"{target}.{a.name}"


CASES = list(modules())


@pytest.mark.parametrize("module,path,is_package", CASES, ids=[m for m, _, _ in CASES])
def test_imports_point_down(module, path, is_package):
    own = layer(module)
    assert own is not None, f"{module} has no layer in LAYERS"
    up = sorted({t for t in imports(module, path, is_package)
                 if t.startswith("delaycomp") and (layer(t) or 0) > own})
    assert not up, f"{module} (layer {own}) imports from above: {up}"
