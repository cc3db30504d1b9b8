"""Native by default (issue 23, item 4): ``build``, ``run``, ``ssp``, ``export-loop`` and
the Python API use the native C FMUs wherever the loop has them here (LTI loops, model
files that translate, a C compiler), the Python FMUs otherwise with a note saying why;
``--python`` (``fmus="python"``) asks for the Python FMUs, ``--native`` for native ones
only (an error where there are none). Every earlier command line keeps working."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from delaycomp import api
from delaycomp.paper import scenarios


def cli(*args, env=None, cwd=None):
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], capture_output=True,
                          text=True, timeout=900, env=env, cwd=cwd)


def _native(fmu: Path) -> bool:
    return not read_model_description(str(fmu)).coSimulation.needsExecutionTool


def _csv(path: Path) -> np.ndarray:
    return np.genfromtxt(path, delimiter=",", skip_header=1)


@pytest.mark.parametrize("scenario", ["example-3.6", "example-3.8"])
def test_run_uses_the_native_fmus_by_default_and_python_on_request(scenario, tmp_path):
    """The default run builds native FMUs into DIR/native and none into DIR; ``--python``
    the Python FMUs into DIR; both print the same trajectory (to 1e-12 of each signal's
    peak: native-vs-python of ``delaycomp check``)."""
    runs = {}
    for label, extra in (("default", []), ("python", ["--python"])):
        folder = tmp_path / label
        proc = cli("run", scenario, "--stop-time", "4", "--fmu-dir", str(folder), "--out",
                   str(tmp_path / f"{label}.csv"), *extra)
        assert proc.returncode == 0, proc.stderr
        assert "note:" not in proc.stderr
        runs[label] = _csv(tmp_path / f"{label}.csv")
        top = sorted(p.name for p in folder.glob("*.fmu"))
        native = sorted((folder / "native").glob("*.fmu"))
        if label == "default":
            assert top == [] and native and all(_native(p) for p in native)
        else:
            assert top and not native and not any(_native(folder / p) for p in top)
    peak = np.maximum(np.abs(runs["python"]).max(axis=0), 1e-300)
    assert np.max(np.abs(runs["default"] - runs["python"]) / peak) <= 1e-12


def test_without_a_compiler_the_python_fmus_run_with_a_note(tmp_path):
    """No C compiler here: the default falls back to the Python FMUs and says why (one
    note, exit 0); ``--native`` is an error (exit 1, one line naming what to install)."""
    env = {**os.environ, "CC": "no-such-compiler"}
    proc = cli("run", "example-3.6", "--stop-time", "2", "--fmu-dir", str(tmp_path),
               env=env)
    assert proc.returncode == 0, proc.stderr
    notes = [line for line in proc.stderr.splitlines() if line.startswith("note:")]
    assert notes == ["note: the Python FMUs run this loop (no native ones here: CC = "
                     "'no-such-compiler' is not allowed: no such program on PATH (set CC to "
                     "a C compiler, or unset it)); --python says so and skips the attempt"]
    assert (tmp_path / "DelaycompPlantLTI.fmu").exists()
    quiet = cli("run", "example-3.6", "--stop-time", "2", "--fmu-dir", str(tmp_path), "-q",
                env=env)
    assert quiet.returncode == 0 and quiet.stderr == ""
    strict = cli("run", "example-3.6", "--stop-time", "2", "--native", "--fmu-dir",
                 str(tmp_path / "strict"), env=env)  # an empty folder: they must be built
    assert strict.returncode != 0 and strict.stderr.count("\n") == 1
    assert "Traceback" not in strict.stderr


def test_native_and_python_together_are_a_usage_error():
    proc = cli("run", "example-3.6", "--native", "--python")
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("delaycomp: error: argument --python: not allowed with "
                                   "argument --native")


def test_ssp_packs_native_fmus_by_default(tmp_path):
    for extra, native in (([], True), (["--python"], False)):
        out = tmp_path / f"loop{len(extra)}.ssp"
        proc = cli("ssp", "example-3.8", "--out", str(out), *extra)
        assert proc.returncode == 0, proc.stderr
        with zipfile.ZipFile(out) as zf:
            inner = [n for n in zf.namelist() if n.endswith(".fmu")]
            assert len(inner) == 4
            for name in inner:
                (tmp_path / "x.fmu").write_bytes(zf.read(name))
                assert _native(tmp_path / "x.fmu") is native, name


def test_build_writes_native_fmus_and_archives_by_default(tmp_path):
    """The README's first command's ``build``: the LTI FMUs and every scenario's archives
    (plain and Jacobi), native; ``--python`` gives the Python ones."""
    out = tmp_path / "fmus"
    proc = cli("build", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    fmus = sorted(out.glob("*.fmu"))
    assert [p.name for p in fmus] == ["DelaycompControllerLTI.fmu", "DelaycompDelay.fmu",
                                      "DelaycompPlantLTI.fmu"]
    assert all(_native(p) for p in fmus)
    archives = sorted(out.glob("*.ssp"))
    assert len(archives) == 2 * len(scenarios.SCENARIOS)
    for archive in archives:
        with zipfile.ZipFile(archive) as zf:
            for name in (n for n in zf.namelist() if n.endswith(".fmu")):
                (tmp_path / "x.fmu").write_bytes(zf.read(name))
                assert _native(tmp_path / "x.fmu"), (archive.name, name)
    run = cli("run", str(out / "example-2.4.ssp"), "--stop-time", "2")
    assert run.returncode == 0, run.stderr


def test_build_model_python_on_request(tmp_path):
    from delaycomp.paper.models import path

    proc = cli("build", "--model", str(path("example_3_8")), "--python", "--out",
               str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert not any(_native(p) for p in tmp_path.glob("*.fmu"))


def test_a_loop_with_a_users_fmu_runs_the_python_fmus_with_a_note(tmp_path):
    """A plant FMU from another tool has no native twin: the default runs the Python
    delays and controller around it and says why."""
    import dataclasses

    from delaycomp.system.loop import FmuFile

    sc = scenarios.get("example-3.6")
    loop = sc.make(sc.resolve([]))
    plant_fmu = api.run(loop, 1.0, fmus="python", fmu_dir=tmp_path / "py")  # builds them
    assert plant_fmu.notes == []
    theirs = tmp_path / "theirs.fmu"
    theirs.write_bytes((tmp_path / "py" / "DelaycompPlantLTI.fmu").read_bytes())
    loop = dataclasses.replace(loop, instances=[
        dataclasses.replace(i, source=FmuFile(theirs)) if i.name == "plant" else i
        for i in loop.instances])
    result = api.run(loop, 1.0, fmu_dir=tmp_path / "py")
    assert result.notes == ["the Python FMUs ran (no native ones here: instance 'plant' is "
                            "a user's FMU file; native FMUs exist for the delay, the "
                            "network channel, the LTI plant and controller, the "
                            "time-stamp controller, and a model file's plant and "
                            "controller)"]


def test_the_api_runs_native_by_default(tmp_path):
    sc = scenarios.get("example-3.8")
    loop = sc.make(sc.resolve([]))
    native = api.run(loop, 3.0, fmu_dir=tmp_path)
    assert native.notes == [] and any((tmp_path / "native").glob("*.fmu"))
    python = api.run(loop, 3.0, fmu_dir=tmp_path, fmus="python")
    assert np.max(np.abs(native.data - python.data)) <= 1e-12
    with pytest.raises(ValueError, match="fmus = 'c' is not allowed: must be one of auto, "
                                         "native, python"):
        api.run(loop, 3.0, fmus="c")
    with pytest.raises(ValueError, match="engine = 'inprocess'"):
        api.run(loop, 3.0, engine="inprocess", fmus="native")
    archive = api.to_ssp(loop, tmp_path / "a.ssp")
    with zipfile.ZipFile(archive) as zf:
        name = next(n for n in zf.namelist() if "Controller" in n)
        (tmp_path / "x.fmu").write_bytes(zf.read(name))
    assert _native(tmp_path / "x.fmu")
