"""Reference traces: independent of the package, and reproducible from their scripts."""

from __future__ import annotations

import ast
import filecmp
import shutil
import subprocess
import sys

import pytest

from .conftest import REPO

SCRIPTS = sorted(p for p in (REPO / "reference").glob("*.py") if p.name != "__init__.py")


def imported_roots(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            roots.add(node.module.split(".")[0])
    return roots


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_reference_script_uses_only_stdlib_numpy_scipy(script):
    foreign = imported_roots(script) - set(sys.stdlib_module_names) - {"numpy", "scipy"}
    assert not foreign, f"{script.name} imports {sorted(foreign)}"


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_reference_script_reproduces_the_stored_traces(script, tmp_path):
    copy = tmp_path / "reference"
    shutil.copytree(REPO / "reference", copy)
    outputs = {p.relative_to(copy) for p in copy.rglob("*_ref.*")}
    for p in outputs:
        (copy / p).unlink()
    proc = subprocess.run([sys.executable, str(copy / script.name)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    made = {p.relative_to(copy) for p in copy.rglob("*_ref.*")}
    assert made, "the script wrote no trace"
    for rel in made:
        assert filecmp.cmp(copy / rel, REPO / "reference" / rel, shallow=False), rel
