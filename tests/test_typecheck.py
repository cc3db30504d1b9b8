"""mypy sees the package as it installs (``scripts/typecheck.py``): ``orchestrator/`` and
``fmus/`` as ``delaycomp.orchestrator`` and ``delaycomp.fmus``, checked for real, not
ignored. The check itself is CI's mypy stage (``.ci/run``); here the tree it checks, the
paths it reports and the configuration."""

from __future__ import annotations

import importlib.util
import sys

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

from .conftest import REPO


def _typecheck():
    spec = importlib.util.spec_from_file_location("typecheck", REPO / "scripts" / "typecheck.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_tree_holds_the_top_level_folders_inside_the_package(tmp_path):
    _typecheck().assemble(tmp_path)
    package = tmp_path / "delaycomp"
    for inside, source in (("api/__init__.py", "delaycomp/api/__init__.py"),
                           ("orchestrator/master.py", "orchestrator/master.py"),
                           ("fmus/controller/delaycomp_model_controller.py",
                            "fmus/controller/delaycomp_model_controller.py"),
                           ("reference/__init__.py", "reference/__init__.py")):
        assert (package / inside).resolve() == (REPO / source).resolve()
    # the reference scripts run as files, importing their shared module by its bare name
    assert not (package / "reference" / "reftools.py").exists()
    assert not (package / "__pycache__").exists()


def test_its_messages_name_the_repository_files(tmp_path):
    typecheck = _typecheck()
    line = f"{tmp_path}/delaycomp/orchestrator/fmu.py:3: error: x  [misc]\n"
    assert typecheck.from_tree(line, tmp_path) == "orchestrator/fmu.py:3: error: x  [misc]\n"
    assert (typecheck.from_tree("delaycomp/fmus/delay/delaycomp_delay.py:1: note: see "
                                "delaycomp/orchestrator/master.py\n", tmp_path)
            == "fmus/delay/delaycomp_delay.py:1: note: see orchestrator/master.py\n")
    # the package's own files and names keep theirs
    assert (typecheck.from_tree("delaycomp/api.py:9: error: delaycomp.fmus.x\n", tmp_path)
            == "delaycomp/api.py:9: error: delaycomp.fmus.x\n")


def test_files_named_on_its_command_line_are_the_trees():
    typecheck = _typecheck()
    assert (typecheck.to_tree(str(REPO / "orchestrator" / "fmu.py"))
            == "delaycomp/orchestrator/fmu.py")
    assert (typecheck.to_tree(str(REPO / "delaycomp" / "api" / "__init__.py"))
            == "delaycomp/api/__init__.py")
    assert typecheck.to_tree("--strict") == "--strict"


def test_no_override_makes_the_master_or_the_fmus_any():
    mypy = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["mypy"]
    assert mypy["files"] == ["delaycomp"]  # the tree's package, orchestrator/ and fmus/ inside
    assert mypy["check_untyped_defs"] is True
    ignored = [m for o in mypy.get("overrides", []) for m in o["module"]]
    assert not [m for m in ignored if m.split(".")[0] == "delaycomp"]
