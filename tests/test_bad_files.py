"""Corrupt or foreign files and failed runs on the command line.

Every bad file gives one line ``delaycomp: error: PATH: REASON``, exit status 2, no
traceback, and nothing written that looks like a result. A run that fails part-way exits
with status 1 and keeps the rows recorded so far only under ``FILE.csv.partial``.
"""

from __future__ import annotations

import csv
import json
import shutil
import zipfile

import pytest

from .test_cli import cli

pytestmark = pytest.mark.fmu

PLANT = "DelaycompPlantLTI.fmu"


def _corrupt_text(path, fmu_dir):
    path.write_text("this is not an FMU\n", encoding="utf-8")


def _truncated(path, fmu_dir):
    data = (fmu_dir / PLANT).read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _foreign(path, fmu_dir):
    shutil.copy2(fmu_dir / "DelaycompDelay.fmu", path)


def _no_model_description(path, fmu_dir):
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("resources/readme.txt", "hello")


def _bad_xml(path, fmu_dir):
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", "<fmiModelDescription><oops")


def _other_version(path, fmu_dir):
    with zipfile.ZipFile(fmu_dir / PLANT) as src, zipfile.ZipFile(path, "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "resources/delaycomp_fmu.json":
                cfg = json.loads(data)
                cfg["version"] = "0.0.0"
                data = json.dumps(cfg).encode()
            dst.writestr(item, data)


def _other_dimensions(path, fmu_dir):
    with zipfile.ZipFile(fmu_dir / PLANT) as src, zipfile.ZipFile(path, "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "resources/delaycomp_fmu.json":
                cfg = json.loads(data)
                cfg["n"] = 2
                data = json.dumps(cfg).encode()
            dst.writestr(item, data)


CASES = {
    "text-file": (_corrupt_text, "is not an FMU: not a zip archive"),
    "truncated": (_truncated, "is not an FMU: not a zip archive"),
    "foreign-fmu": (_foreign, "is an FMU of model 'DelaycompDelay', expected "
                              "'DelaycompPlantLTI'"),
    "no-model-description": (_no_model_description,
                             "is not an FMU: it has no modelDescription.xml"),
    "bad-xml": (_bad_xml, "is not a readable FMU: "),
    "other-version": (_other_version, "was built by delaycomp '0.0.0', this is '0.1.0'"),
    "other-dimensions": (_other_dimensions, "was built for {'n': 2}, this loop needs "
                                            "{'n': 1}"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_fmu_in_fmu_dir_is_one_line_exit_2(fmu_dir, tmp_path, case):
    make, message = CASES[case]
    folder = tmp_path / "fmus"
    shutil.copytree(fmu_dir, folder)
    make(folder / PLANT, fmu_dir)
    out = tmp_path / "out" / "result.csv"
    out.parent.mkdir()  # an output's folder must exist (issue 30, item 9)
    proc = cli("run", "example-3.6", "--python", "--fmu-dir", str(folder), "--out", str(out),
               "--plot", str(tmp_path / "out" / "result.png"))
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith(f"delaycomp: error: {folder / PLANT}: {message}")
    assert not any((tmp_path / "out").iterdir())  # nothing written


@pytest.mark.parametrize("fmus", [[], ["--python"], ["--native"]], ids=str)
def test_fmu_dir_that_is_a_file_is_one_line_exit_2(tmp_path, fmus):
    not_a_dir = tmp_path / "fmus"
    not_a_dir.write_text("x", encoding="utf-8")
    proc = cli("run", "example-3.6", *fmus, "--fmu-dir", str(not_a_dir))
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"delaycomp: error: {not_a_dir}: is not a folder "
                                   "(--fmu-dir wants a folder of FMUs)")


@pytest.mark.parametrize("fmus", [[], ["--native"]], ids=str)
def test_bad_native_fmu_in_fmu_dir_is_one_line_exit_2(tmp_path, fmus):
    """The native FMUs of ``--fmu-dir DIR`` live in DIR/native (the default and
    ``--native``): a corrupt one there is refused, not replaced or skipped."""
    folder = tmp_path / "fmus" / "native"
    folder.mkdir(parents=True)
    (folder / "DelaycompPlantLTI.fmu").write_text("not an fmu", encoding="utf-8")
    proc = cli("run", "example-3.6", *fmus, "--fmu-dir", str(tmp_path / "fmus"),
               "--stop-time", "1")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0] == (f"delaycomp: error: {folder / 'DelaycompPlantLTI.fmu'}: is not an "
                        "FMU: not a zip archive")


def test_failed_run_writes_only_a_partial_file(fmu_dir, tmp_path):
    """u = -k Phi with k = 1e300 overflows at the second sample: the controller refuses and
    the run stops; FILE.csv and the plot are not written, FILE.csv.partial holds the rows
    up to the failure."""
    out = tmp_path / "result.csv"
    plot = tmp_path / "result.png"
    proc = cli("run", "example-3.6", "--fmu-dir", str(fmu_dir), "--set", "k=1e300",
               "--set", "N=2", "--set", "r=0", "--stop-time", "5", "--out", str(out),
               "--plot", str(plot))
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("delaycomp: error: controller failed at t = 1: control "
                               "['u'] = [inf] at t = 1.0 is not allowed: must be finite")
    partial = tmp_path / "result.csv.partial"
    assert lines[0].endswith(f"; 2 rows to t = 0.5 kept in {partial}")
    assert not out.exists() and not plot.exists()
    with open(partial, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][0] == "time" and len(rows) == 3
