"""The command-line contract: forms, CSV columns, plots, and one-line errors."""

from __future__ import annotations

import csv
import os
import subprocess
import sys

import pytest

from .conftest import REPO

pytestmark = pytest.mark.fmu


def cli(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "delaycomp.cli", *args], capture_output=True,
                          text=True, cwd=cwd or REPO, timeout=300,
                          env={**os.environ, **(env or {})})


BAD = [
    (["run", "example-9.9"], "unknown scenario 'example-9.9'"),
    (["run", "example-3.6", "--set", "T=0"], "T = '0' is not allowed: must be a finite number > 0"),
    (["run", "example-3.6", "--set", "T=-1"], "T = '-1'"),
    (["run", "example-3.6", "--set", "r=-0.1"], "r = '-0.1' is not allowed: must be a finite "
                                                 "number >= 0"),
    (["run", "example-3.6", "--set", "tau=0.5"], "tau = 0.5 is not allowed: must be a multiple"),
    (["run", "example-3.6", "--set", "N=0"], "N = '0' is not allowed: must be a positive integer"),
    (["run", "example-3.6", "--set", "N=2.5"], "N = '2.5'"),
    (["run", "example-3.6", "--set", "k=inf"], "k = 'inf' is not allowed: must be a finite"),
    (["run", "example-3.6", "--set", "x0=nan"], "x0 = 'nan'"),
    (["run", "example-3.6", "--set", "mode=fast"], "mode = 'fast' is not allowed: must be "
                                                   "compensated or uncompensated"),
    (["run", "example-3.6", "--set", "speed=1"], "unknown parameter 'speed'"),
    (["run", "example-3.6", "--set", "k"], "expected NAME=VALUE"),
    (["run", "example-3.6", "--set", "r=0.205"], "must be a multiple of the base step"),
    (["run", "example-3.6", "--stop-time", "-3"], "--stop-time -3.0 is not allowed"),
    (["run", "example-3.6", "--stop-time", "nan"], "--stop-time nan is not allowed"),
    (["critical-delay", "example-3.6", "--set", "T=abc"], "T = 'abc'"),
    (["frobnicate"], "invalid choice"),
]


@pytest.mark.parametrize("args,message", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_input_is_one_line_exit_2_no_traceback(args, message):
    proc = cli(*args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("delaycomp: error: ")
    assert message in lines[0]
    assert "Traceback" not in proc.stderr


def test_run_writes_csv_and_plot(tmp_path, fmu_dir):
    out, png = tmp_path / "fig2.csv", tmp_path / "fig2.png"
    proc = cli("run", "example-3.6", "--set", "r=0.3", "--set", "mode=uncompensated",
               "--stop-time", "5", "--out", str(out), "--plot", str(png),
               "--fmu-dir", str(fmu_dir))
    assert proc.returncode == 0, proc.stderr
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time", "plant.x", "controller.u"]
    assert len(rows) == 1 + 501  # one row per base step, 0 .. 5 with h = 0.01
    assert float(rows[-1][0]) == 5.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob("*.part*"))


def test_critical_delay_prints_r_c_and_confirms(fmu_dir):
    proc = cli("critical-delay", "example-3.6", "--periods", "20", "--fmu-dir", str(fmu_dir))
    assert proc.returncode == 0, proc.stderr
    first, *rest = proc.stdout.splitlines()
    assert first.startswith("r_c = ")
    r_c = float(first.split("=")[1])
    assert 0.20 < r_c < 0.21
    assert len(first.split("=")[1].strip().split(".")[1]) >= 6  # at least 6 decimals
    assert any(line.startswith("confirmed below") and "(stable)" in line for line in rest)
    assert any(line.startswith("confirmed above") and "(unstable)" in line for line in rest)


def test_build_writes_three_valid_fmus_and_an_ssp_per_scenario(tmp_path):
    from delaycomp.scenarios import SCENARIOS

    proc = cli("build", "--out", str(tmp_path / "fmus"))
    assert proc.returncode == 0, proc.stderr
    names = sorted(p.name for p in (tmp_path / "fmus").glob("*.fmu"))
    assert names == ["DelaycompControllerLTI.fmu", "DelaycompDelay.fmu", "DelaycompPlantLTI.fmu"]
    packed = sorted(p.name for p in (tmp_path / "fmus").glob("*.ssp"))
    assert packed == sorted(f"{name}{variant}.ssp" for name in SCENARIOS
                            for variant in ("", "-jacobi"))


def test_list_names_every_parameter():
    proc = cli("list")
    assert proc.returncode == 0
    for name in ("k", "T", "r", "tau", "N", "mode", "x0", "u0"):
        assert f"    {name} " in proc.stdout
