"""No time that rounds to nothing (issue 30, item 8).

A stop time, an output interval or a sampling period whose number of base steps rounds to
zero is refused in one line (exit 2), never run as zero steps with exit 0 (before:
``--stop-time 1e-320`` wrote one row and exited 0, ``--output-interval 1e-320`` was taken
as one step, a loop with ``T = 1e10`` and stop time 1 ran no step)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from delaycomp.errors import ParameterError
from delaycomp.maths.grid import ticks


def _cli(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_a_duration_that_rounds_to_no_step_is_refused():
    assert ticks(0.01, 1.0, 100) == 1
    for duration, T, N in [(1e-320, 1.0, 100), (1.0, 1e10, 1), (5e-324, 1e-300, 1)]:
        with pytest.raises(ValueError, match="is less than one base step"):
            ticks(duration, T, N)


@pytest.mark.parametrize("args,message", [
    (["run", "example-3.6", "--stop-time", "1e-320"],
     "--stop-time 1e-320 is not allowed: it is less than one base step h = T/N = 0.01"),
    (["run", "example-3.6", "--output-interval", "1e-320", "--out", "x.csv"],
     "--output-interval 1e-320 is not allowed: it is less than one base step h = T/N = 0.01"),
    (["sweep", "example-3.6", "--grid", "k=1:2:2", "--stop-time", "1e-320", "--out", "s.csv"],
     "grid point k=1: --stop-time 1e-320 is not allowed: it is less than one base step "
     "h = T/N = 0.01"),
    (["run", "loop.toml"],
     "--stop-time 1.0 is not allowed: it is less than one base step h = T/N = 10000000000.0"),
])
def test_the_command_line_refuses_it_in_one_line(tmp_path, args, message):
    (tmp_path / "loop.toml").write_text(
        "T = 1e10\nN = 1\nr = 0\ntau = 0\nstop_time = 1.0\n[plant]\nA = [[-1.0]]\n"
        "B = [[1.0]]\nx0 = [1.0]\n[controller]\nK = [[-0.5]]\n", encoding="utf-8")
    proc = _cli(*args, cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip() == f"delaycomp: error: {message}"
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "s.csv").exists()


def test_the_api_refuses_it():
    from delaycomp import api

    loop = api.lti([[-1.0]], [[1.0]], [[-0.5]], T=1.0, x0=[1.0])
    with pytest.raises(ParameterError, match="less than one base step"):
        api.run(loop, 1e-320, engine="inprocess")


def test_the_default_watchdog_of_a_huge_period_is_finite():
    """``--period 1e308`` made the default watchdog infinite, refused as if the user had
    given it; it is at most a day."""
    from delaycomp.orchestrator.isolated import default_watchdog

    assert default_watchdog(1e308) == 86400.0
