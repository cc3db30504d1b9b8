"""Exit 2 and one line for every bad input (issue 30, item 9).

Values that overflow in the design checks, inputs nested too deeply to parse, output paths
under a missing or unwritable folder get the one-line form naming the input, exit 2; Ctrl-C
inside a component's Python code is the user's interrupt (exit 130), not a plant failure.
Before: ``Array must not contain infs or NaNs`` and ``maximum recursion depth exceeded``
with exit 1, output folders created silently or a raw errno with exit 1, and Ctrl-C
reported as ``plant failed at t = ...: ... KeyboardInterrupt`` with exit 1.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

LOOP = """T = {T}
N = 10
r = 0.3
tau = 0.0
stop_time = 2.0
[plant]
A = [[{A}]]
B = [[1.0]]
x0 = [1.0]
[controller]
K = [[-0.5]]
"""


def _cli(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def _one_line(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 2, proc.stdout + proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert len(err) < 400, err  # one readable line: a long input is quoted in part
    return err


@pytest.mark.parametrize("T,A,what", [("1.0", "1e308", "plant A = [[1e+308]] with T = 1.0"),
                                      ("1e308", "1.0", "plant A = [[1.0]] with T = 1e+308")])
def test_a_design_that_overflows_is_refused_naming_the_input(tmp_path, T, A, what):
    (tmp_path / "loop.toml").write_text(LOOP.format(T=T, A=A), encoding="utf-8")
    err = _one_line(_cli("run", "loop.toml", "--engine", "inprocess", cwd=tmp_path))
    assert err.startswith(f"delaycomp: error: {what} is not allowed: the sampled plant "
                          "e^(A T) overflows (it is not finite)")


DEEP = "[" * 50000 + "1.0" + "]" * 50000


def test_a_loop_file_nested_too_deeply_is_refused(tmp_path):
    (tmp_path / "deep.toml").write_text(f"x = {DEEP}\n", encoding="utf-8")
    err = _one_line(_cli("run", "deep.toml", cwd=tmp_path))
    assert err == ("delaycomp: error: deep.toml: is not allowed: its arrays or tables are "
                   "nested too deeply to read (a loop needs at most a matrix: two levels)")


@pytest.mark.parametrize("source,key", [("example-3.6", "x0"), ("loop.toml", "plant.x0")])
def test_a_value_nested_too_deeply_is_refused(tmp_path, source, key):
    (tmp_path / "loop.toml").write_text(LOOP.format(T="1.0", A="1.0"), encoding="utf-8")
    err = _one_line(_cli("run", source, "--set", f"{key}={DEEP}", cwd=tmp_path))
    assert "..." in err and key in err


def test_ssp_annotations_nested_too_deeply_are_refused(tmp_path):
    proc = _cli("ssp", "example-3.6", "--python", "--out", "good.ssp", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    with zipfile.ZipFile(tmp_path / "good.ssp") as zin, \
            zipfile.ZipFile(tmp_path / "deep.ssp", "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "SystemStructure.ssd":
                text = data.decode()
                start = text.index('config="') + len('config="')
                end = text.index('"', start)
                text = text[:start] + DEEP.replace("1.0", "") + text[end:]
                data = text.encode()
            zout.writestr(item, data)
    err = _one_line(_cli("run", "deep.ssp", cwd=tmp_path))
    assert "is not JSON (or is nested too deeply)" in err


def test_an_output_under_a_missing_folder_is_refused_and_nothing_created(tmp_path):
    err = _one_line(_cli("run", "example-3.6", "--engine", "inprocess", "--out",
                         "results/run.csv", cwd=tmp_path))
    assert err == ("delaycomp: error: --out 'results/run.csv': folder results does not exist "
                   "(create it first)")
    assert not (tmp_path / "results").exists()


@pytest.mark.skipif(not Path("/sys").is_dir(), reason="needs Linux's /sys")
def test_an_output_where_no_file_can_be_made_is_refused(tmp_path):
    """/sys refuses new files to everyone, root included (where permissions say nothing)."""
    err = _one_line(_cli("run", "example-3.6", "--engine", "inprocess", "--out",
                         "/sys/run.csv", cwd=tmp_path))
    assert err.startswith("delaycomp: error: --out '/sys/run.csv': folder /sys is not "
                          "writable (")


SLOW_MODEL = '''
import time
import numpy as np
STATES = ("x",)
INPUTS = ("u",)
CONTROL = "zoh"
PARAMETERS = {}

def f(x, u, p):
    time.sleep(0.002)  # most of the run is spent here: Ctrl-C lands in the model's code
    return np.array([-x[0] + u[0]])

def k(x, p):
    return np.array([-0.5 * x[0]])
'''

SLOW_LOOP = """T = 0.5
N = 5
r = 0.1
tau = 0.0
stop_time = 1000.0
[plant]
model = "slow.py"
x0 = [1.0]
[controller]
predictor = "numerical"
"""


@pytest.mark.parametrize("engine", ["inprocess", "fmu"])
def test_ctrl_c_inside_a_models_code_is_an_interrupt_not_a_failure(tmp_path, engine):
    (tmp_path / "slow.py").write_text(SLOW_MODEL, encoding="utf-8")
    (tmp_path / "loop.toml").write_text(SLOW_LOOP, encoding="utf-8")
    proc = subprocess.Popen([sys.executable, "-m", "delaycomp", "run", "loop.toml",
                             "--engine", engine, "--python", "--out", "o.csv"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "o.csv.part").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert re.fullmatch(r"delaycomp: interrupted at t = \d+(\.\d+)?",
                        err.strip().splitlines()[-1]), err
    assert "failed" not in err and "KeyboardInterrupt" not in err
    assert (tmp_path / "o.csv.partial").exists()  # the rows so far, kept
