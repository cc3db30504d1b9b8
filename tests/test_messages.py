"""Messages that tell the fix (issue 27, item 5).

- the zero-order-hold rule ``tau = l T``: wherever it refuses a ``tau`` (a scenario's
  ``--set``, a loop file, a sweep over ``T`` or over ``tau``, the batch engine) the one
  line names the nearest allowed values (multiples of ``T`` around ``tau``, periods
  ``tau / l`` around ``T``) and, where padding is offered, that ``pad = true`` accepts it;
  never "raise N" (no ``N`` helps);
- Ctrl-C: ``delaycomp: interrupted at t = ...`` (the time reached), exit 130;
- ``-v``: one line per FMU built or found in the cache;
- progress bars on any terminal (a pty), ``--progress`` / ``--no-progress``.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .conftest import REPO

LOOPS = REPO / "delaycomp" / "paper" / "loops"


def cli(*args, cwd=None, env=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], capture_output=True,
                          text=True, cwd=cwd or REPO, timeout=timeout,
                          env={**os.environ, **(env or {})})


def one_error_line(proc) -> str:
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("delaycomp: error: ")
    return lines[0]


def _multiple(value: float, step: float) -> bool:
    q = value / step
    return abs(q - round(q)) <= 1e-9 * max(1.0, abs(q))


def check_zoh_line(line: str, tau: float, T: float, pad: bool) -> None:
    """The line names tau, T, the multiples of T just below and above tau, the periods
    tau/l just below and above T, and pad exactly where padding is offered."""
    assert "raise N" not in line
    assert f"tau = {tau!r} is not allowed: zero-order hold needs a multiple l*T" in line
    found = re.search(r"the nearest allowed are tau = (\S+) or (\S+) \(l\*T\), or T = "
                      r"(\S+)(?: or (\S+))? \(tau/l\)", line)
    assert found, line
    lo, hi = float(found[1]), float(found[2])
    assert _multiple(lo, T) and _multiple(hi, T) and lo < tau < hi
    assert math.isclose(hi - lo, T, rel_tol=1e-9)  # the two neighbours, nothing between
    periods = [float(x) for x in found.groups()[2:] if x is not None]
    assert all(_multiple(tau, p) for p in periods)
    assert min(periods) < T and (len(periods) == 1 or max(periods) > T)
    ls = sorted(round(tau / p) for p in periods)
    assert ls == list(range(ls[0], ls[0] + len(ls)))  # tau/l for consecutive l: the nearest
    if pad:
        after = re.search(r"; or pad = true \(\[controller\] pad in a loop file, --set pad=1 "
                          r"for a scenario\) accepts it, delaying the output to the next "
                          r"multiple, (\S+) \(Remark 3\.3\(b\)\)$", line)
        assert after, line
        assert float(after[1]) == hi
    else:
        assert "pad" not in line


@pytest.mark.parametrize("args,tau,T,pad", [
    (["run", "example-3.6", "--set", "tau=0.5"], 0.5, 1.0, False),
    (["run", "example-3.8", "--set", "tau=0.5"], 0.5, 1.0, True),
    (["run", "example-3.8", "--set", "tau=2.5", "--set", "T=0.7", "--set", "r=0.7"], 2.5, 0.7, True),
    (["run", str(LOOPS / "example-3.6.toml"), "--set", "tau=0.5"], 0.5, 1.0, False),
    (["run", str(LOOPS / "example-3.8.toml"), "--set", "tau=1.5"], 1.5, 1.0, True),
    (["critical-delay", "example-3.6", "--set", "tau=0.5"], 0.5, 1.0, False),
], ids=["scenario", "scenario-pad", "scenario-pad-T", "loop", "loop-pad", "critical"])
def test_the_zoh_rule_names_the_nearest_values_and_pad(args, tau, T, pad):
    check_zoh_line(one_error_line(cli(*args)), tau, T, pad)


@pytest.mark.parametrize("engine", ["batch", "inprocess"])
@pytest.mark.parametrize("source,sets,pad", [
    ("example-3.6", [], False),
    ("example-3.8", ["--set", "r=0"], True),
    (str(LOOPS / "example-3.6.toml"), [], False),
], ids=["lti", "model-pad", "loop"])
def test_a_sweep_over_T_tells_the_zoh_fix_not_raise_N(tmp_path, engine, source, sets, pad):
    """tau = 1 and T = 0.3 (h = 0.003): tau is off the base grid too, but no N puts it on
    a multiple of T; the line names the fix of the rule that binds."""
    line = one_error_line(cli("sweep", source, *sets, "--set", "tau=1", "--grid",
                              "T=0.3:1:3", "--engine", engine, "--out",
                              str(tmp_path / "s.csv")))
    assert line.startswith("delaycomp: error: grid point T=0.3: ")
    check_zoh_line(line, 1.0, 0.3, pad)


def test_a_sweep_over_tau_tells_the_zoh_fix(tmp_path):
    line = one_error_line(cli("sweep", "example-3.8", "--grid", "tau=0.5:1:2", "--out",
                              str(tmp_path / "s.csv")))
    assert line.startswith("delaycomp: error: grid point tau=0.5: ")
    check_zoh_line(line, 0.5, 1.0, True)


def test_a_delay_off_the_base_grid_names_an_N_that_holds_it_not_raise_N():
    """r = 0.5 with T = 0.3, N = 100: no N > 100 that is not a multiple of 3 holds r; the
    line names the neighbours on h = 0.003 and the smallest N that works."""
    line = one_error_line(cli("run", "example-3.6", "--set", "T=0.3", "--set", "r=0.5"))
    assert "raise N" not in line
    found = re.search(r"r = 0\.5 is not allowed: must be a multiple of the base step "
                      r"h = T/N = (\S+): the nearest allowed are (\S+) or (\S+), or N = "
                      r"(\d+) puts it on the grid$", line)
    assert found, line
    h, lo, hi, n = float(found[1]), float(found[2]), float(found[3]), int(found[4])
    assert math.isclose(h, 0.3 / 100)
    assert _multiple(lo, h) and _multiple(hi, h) and lo < 0.5 < hi
    assert math.isclose(hi - lo, h, rel_tol=1e-9)
    assert n >= 100 and _multiple(0.5, 0.3 / n)
    assert not any(_multiple(0.5, 0.3 / k) for k in range(100, n))  # the smallest
