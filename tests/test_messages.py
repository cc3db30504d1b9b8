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
    (["run", "example-3.6", "--set", "tau=0.5"], 0.5, 1.0, True),  # the LTI loop pads too
    (["run", "example-3.8", "--set", "tau=0.5"], 0.5, 1.0, True),
    (["run", "example-3.8", "--set", "tau=2.5", "--set", "T=0.7", "--set", "r=0.7"], 2.5,
     0.7, True),
    (["run", str(LOOPS / "example-3.6.toml"), "--set", "tau=0.5"], 0.5, 1.0, True),
    (["run", str(LOOPS / "example-3.8.toml"), "--set", "tau=1.5"], 1.5, 1.0, True),
    (["critical-delay", "example-3.6", "--set", "tau=0.5"], 0.5, 1.0, True),
], ids=["scenario", "scenario-pad", "scenario-pad-T", "loop", "loop-pad", "critical"])
def test_the_zoh_rule_names_the_nearest_values_and_pad(args, tau, T, pad):
    check_zoh_line(one_error_line(cli(*args)), tau, T, pad)


@pytest.mark.parametrize("engine", ["batch", "inprocess"])
@pytest.mark.parametrize("source,sets,pad", [
    ("example-3.6", [], True),  # the LTI loop pads too (issue 50, item 5)
    ("example-3.8", ["--set", "r=0"], True),
    (str(LOOPS / "example-3.6.toml"), [], True),
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


# -- -v: FMU builds and cache hits ------------------------------------------------------

@pytest.mark.parametrize("kind", ["--native", "--python"])
def test_verbose_tells_each_fmu_built_then_each_cache_hit(tmp_path, kind):
    import fmpy

    env = {"DELAYCOMP_CACHE_DIR": str(tmp_path / "cache")}
    args = ("run", "example-3.6", "--stop-time", "1", kind, "--out", str(tmp_path / "o.csv"))
    idents = ("DelaycompPlantLTI", "DelaycompDelay", "DelaycompControllerLTI")
    quiet = cli(*args, env={"DELAYCOMP_CACHE_DIR": str(tmp_path / "other")})
    assert quiet.returncode == 0, quiet.stderr
    assert "building" not in quiet.stderr and "cache hit" not in quiet.stderr  # no -v

    first = cli(*args, "-v", env=env)
    assert first.returncode == 0, first.stderr
    built = re.findall(r"^building (\S+) \((.+?)\) into (.+) \.\.\.$", first.stderr, re.M)
    assert sorted(b[0] for b in built) == sorted(idents)  # each once: no hit after a build
    assert "cache hit" not in first.stderr
    for _, how, folder in built:
        if kind == "--native":
            assert how.split(", ")[0] == "native"
            assert how.split(", ")[1].split()[0] == fmpy.platform  # this machine first
        else:
            assert how == "Python, pythonfmu"
        assert Path(folder).parent == tmp_path / "cache"

    second = cli(*args, "-v", env=env)
    assert second.returncode == 0, second.stderr
    hits = re.findall(r"^cache hit: (\S+) \((.+)\)$", second.stderr, re.M)
    assert sorted(h[0] for h in hits) == sorted(idents)
    assert all(Path(p).is_file() and Path(p).parent.parent == tmp_path / "cache"
               for _, p in hits)
    assert "building" not in second.stderr

    third = cli(*args, env=env)
    assert third.returncode == 0, third.stderr
    assert "cache hit" not in third.stderr and "building" not in third.stderr


def test_verbose_build_of_a_loop_file_tells_each_fmu(tmp_path):
    proc = cli("build", str(LOOPS / "example-3.6.toml"), "--out", str(tmp_path), "-v")
    assert proc.returncode == 0, proc.stderr
    built = re.findall(r"^building (\S+) \((.+?)\) into (.+) \.\.\.$", proc.stderr, re.M)
    assert {b[0] for b in built} >= {"DelaycompPlantLTI", "DelaycompDelay",
                                     "DelaycompControllerLTI"}
    plain = cli("build", str(LOOPS / "example-3.6.toml"), "--out", str(tmp_path / "q"))
    assert plain.returncode == 0, plain.stderr
    assert "building" not in plain.stderr


# -- progress bars -----------------------------------------------------------------------

def on_a_pty(*args, timeout: float = 300) -> tuple[int, str]:
    """Run the command with standard error on a pseudo-terminal (as ``script`` gives one:
    size 0 x 0, never set); its exit status and what reached the terminal."""
    import select

    master, slave = os.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "delaycomp", *args], cwd=REPO,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=slave)
    os.close(slave)
    out = b""
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the slave side closed (Linux: EIO)
                    break
                if not data:
                    break
                out += data
            elif proc.poll() is not None:
                break
        rc = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    return rc, out.decode(errors="replace")


BAR = re.compile(r"\d+%\|.*\| \d+/(\d+) \[")


@pytest.mark.parametrize("command", [
    ("run", "example-3.6", "--engine", "inprocess", "--stop-time", "50"),
    ("sweep", "example-3.6", "--grid", "k=1:2:4", "--workers", "1", "--engine",
     "inprocess", "--stop-time", "5"),
], ids=["run", "sweep"])
def test_a_bar_shows_on_a_pseudo_terminal(tmp_path, command):
    rc, seen = on_a_pty(*command, "--out", str(tmp_path / "o.csv"))
    assert rc == 0, seen
    totals = {int(t) for t in BAR.findall(seen)}
    assert totals == ({5000} if command[0] == "run" else {4}), seen  # steps, or points
    for off in (("--no-progress",), ("-q",)):
        rc, seen = on_a_pty(*command, *off, "--out", str(tmp_path / "o.csv"))
        assert rc == 0, seen
        assert not BAR.search(seen), seen


@pytest.mark.parametrize("command", [
    ("run", "example-3.6", "--engine", "inprocess", "--stop-time", "50"),
    ("sweep", "example-3.6", "--grid", "k=1:2:4", "--workers", "1", "--engine",
     "inprocess", "--stop-time", "5"),
], ids=["run", "sweep"])
def test_progress_forces_a_bar_into_a_pipe_and_no_progress_or_quiet_keep_it_off(
        tmp_path, command):
    out = ("--out", str(tmp_path / "o.csv"))
    forced = cli(*command, *out, "--progress")
    assert forced.returncode == 0, forced.stderr
    assert BAR.search(forced.stderr), forced.stderr
    quiet_forced = cli(*command, *out, "-q", "--progress")
    assert quiet_forced.returncode == 0 and BAR.search(quiet_forced.stderr)
    for args in ((), ("--no-progress",), ("-q",)):
        proc = cli(*command, *out, *args)
        assert proc.returncode == 0, proc.stderr
        assert not BAR.search(proc.stderr), (args, proc.stderr)
    both = cli(*command, *out, "--progress", "--no-progress")
    assert both.returncode == 2 and "not allowed with argument" in both.stderr


# -- Ctrl-C --------------------------------------------------------------------------------

INTERRUPTED_AT = re.compile(r"delaycomp: interrupted at t = (\S+)")


def _children_with(folder: Path, marker: str) -> list[int]:
    """Processes with ``folder`` and ``marker`` on their command line."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(
                    errors="replace")
            except OSError:
                continue
            if str(folder) in cmd and marker in cmd:
                found.append(int(entry.name))
    return found


def interrupt(args, cwd: Path, started, after: float = 0.0, timeout: float = 120,
              env: dict | None = None):
    """Start ``delaycomp ARGS`` in a process group of its own (with ``env``), wait until
    ``started()`` says it has (polled), then ``after`` seconds more, and send SIGINT to the
    group as a terminal's Ctrl-C does; the exit status and standard error."""
    proc = subprocess.Popen([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env=env)
    try:
        deadline = time.monotonic() + timeout
        while not started() and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        assert started(), "the command did not start in time"
        time.sleep(after)
        assert proc.poll() is None, proc.communicate()  # still running: interrupted below
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, err


def check_interrupted_run(rc: int, err: str, partial: Path, stop: float, h: float) -> float:
    """Exit 130, one last line naming the time reached, which the rows kept in
    ``partial`` reach too (a row per base step: the last one within a step of it)."""
    assert rc == 130, err
    assert "Traceback" not in err and "failed" not in err and "error" not in err, err
    found = INTERRUPTED_AT.fullmatch(err.strip().splitlines()[-1])
    assert found, err
    t = float(found[1])
    assert 0 <= t < stop
    rows = partial.read_text().splitlines()
    last = float(rows[-1].split(",")[0])
    assert last <= t + 1e-9 * stop and t - last <= h * (1 + 1e-9), (t, last)
    return t


@pytest.mark.parametrize("engine", ["fmu", "fmu-python-master", "inprocess"])
def test_ctrl_c_during_a_run_names_the_time_reached(tmp_path, engine):
    """The native FMUs stepped by the native core (``fmu``, the default), by the Python
    master, and the in-process engine."""
    out = tmp_path / "o.csv"
    part = tmp_path / "o.csv.part"
    how = (["--stepping", "python"] if engine == "fmu-python-master"
           else ["--stepping", "native-core"] if engine == "fmu" else [])
    rc, err = interrupt(["run", "example-3.6", "--stop-time", "100000", "--engine",
                         engine.split("-")[0], *how, "--out", str(out)], tmp_path,
                        part.exists, after=0.5)
    t = check_interrupted_run(rc, err, tmp_path / "o.csv.partial", 100000.0, 0.01)
    assert t > 0  # it ran a while: half a second
    assert not out.exists() and not part.exists()


def test_ctrl_c_during_a_replayed_run_names_the_time_reached(tmp_path):
    """A run replayed from the recipe of its first run (``delaycomp.cli.recipes``): the
    same exit status and last line, and the rows to the time reached in ``.partial``."""
    archive = tmp_path / "ex36.ssp"
    subprocess.run([sys.executable, "-m", "delaycomp", "ssp", "example-3.6", "--native",
                    "--out", str(archive), "-q"], check=True, capture_output=True)
    argv = ["run", str(archive), "--stop-time", "50000", "--output-interval", "5", "-v"]
    first = subprocess.run([sys.executable, "-m", "delaycomp", *argv, "--out",
                            str(tmp_path / "first.csv")], capture_output=True, text=True)
    assert first.returncode == 0 and "recipe kept" in first.stderr, first.stderr
    out = tmp_path / "o.csv"
    part = tmp_path / "o.csv.part"
    rc, err = interrupt([*argv, "--out", str(out)], tmp_path, part.exists, after=0.2)
    assert "replayed from the recipe of its first run" in err, err
    assert rc == 130 and "Traceback" not in err and "error" not in err, err
    found = INTERRUPTED_AT.fullmatch(err.strip().splitlines()[-1])
    assert found, err
    t = float(found[1])
    rows = (tmp_path / "o.csv.partial").read_text().splitlines()
    last = float(rows[-1].split(",")[0])
    assert 0 < t < 50000 and last <= t and t - last <= 5.0 + 1e-9 * t, (t, last)
    assert not out.exists() and not part.exists()


PLANT_LOOP = """T = 0.5
N = 10
r = 0.3
tau = 0.5
stop_time = 100000.0
[plant]
fmu = "Oscillator.fmu"
states = ["position", "velocity"]
inputs = ["force"]
x0 = [1.0, 0.0]
[controller]
A = [[0, 1], [1, -0.2]]
B = [[0], [1]]
K = [[-3.0, -2.5]]
"""


@pytest.fixture
def plant_loop(tmp_path):
    """A loop whose plant is an FMU of another tool (C, run in a child process)."""
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Oscillator.fmu")
    (tmp_path / "loop.toml").write_text(PLANT_LOOP, encoding="utf-8")
    yield tmp_path
    for pid in _children_with(tmp_path, "delaycomp.orchestrator.isolated"):
        os.kill(pid, signal.SIGKILL)


def test_ctrl_c_with_a_plant_fmu_of_another_tool_names_the_time_reached(plant_loop):
    rc, err = interrupt(["run", "loop.toml", "--out", "o.csv"], plant_loop,
                        (plant_loop / "o.csv.part").exists, after=0.5)
    check_interrupted_run(rc, err, plant_loop / "o.csv.partial", 100000.0, 0.05)
    assert _children_with(plant_loop, "delaycomp.orchestrator.isolated") == []


@pytest.mark.parametrize("after", [0.0, 0.1, 0.2, 0.3, 0.4, 0.6])
def test_ctrl_c_while_the_loop_starts_is_no_plant_failure(plant_loop, after):
    """SIGINT from the moment the plant's child process exists, while it still imports
    (before it could ignore SIGINT) and while the other FMUs (Python FMUs here) are
    instantiated: before, the child could die of the KeyboardInterrupt, with its
    traceback, an interrupt inside a Python FMU's instantiation or logger callback was
    dropped (the run went on) or crashed the process, or it was reported as a failure."""
    rc, err = interrupt(["run", "loop.toml", "--out", "o.csv"], plant_loop,
                        lambda: bool(_children_with(plant_loop,
                                                    "delaycomp.orchestrator.isolated")),
                        after=after, timeout=60)
    assert rc == 130, err
    assert "Traceback" not in err and "failed" not in err and "KeyboardInterrupt" not in err
    assert re.fullmatch(r"delaycomp: interrupted( at t = \S+)?", err.strip().splitlines()[-1])
    time.sleep(0.5)
    assert _children_with(plant_loop, "delaycomp.orchestrator.isolated") == []


def test_ctrl_c_during_a_sweep_with_workers(tmp_path):
    out = tmp_path / "s.csv"
    part = tmp_path / "s.csv.part"
    rc, err = interrupt(["sweep", "example-3.6", "--grid", "k=0.5:2.5:2000", "--workers", "2",
                         "--engine", "inprocess", "--stop-time", "200", "--out", str(out)],
                        tmp_path, part.exists, after=0.5)
    assert rc == 130, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "delaycomp: interrupted"  # many runs: no one time
    assert not out.exists() and not part.exists()  # no half-written result, as before
    assert _children_with(tmp_path, "multiprocessing") == []


def test_a_failure_that_follows_ctrl_c_is_reported_as_the_interrupt(monkeypatch, capsys):
    """Code that catches every exception (an FMU's slave, a build step) can turn Ctrl-C
    into its own error; the command line reports the interrupt, exit 130."""
    from delaycomp import cli
    from delaycomp.errors import ParameterError

    def swallowing(args):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt as exc:  # as a slave does: its own failure
            raise ParameterError(f"controller: initialization failed: {exc!r}") from None
        return 0

    monkeypatch.setattr(cli, "cmd_list", swallowing)
    assert cli.main(["list"]) == 130
    assert capsys.readouterr().err == "delaycomp: interrupted\n"
    monkeypatch.setattr(cli, "cmd_list", lambda args: 0)
    assert cli.main(["list"]) == 0  # the watch ended with the command
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_ctrl_c_during_a_build_is_one_line(tmp_path):
    out = tmp_path / "fmus"
    env_cache = tmp_path / "cache"
    proc_env = {**os.environ, "DELAYCOMP_CACHE_DIR": str(env_cache)}
    # interrupted once the first FMU is out, more to come
    returncode, err = interrupt(["build", "--out", str(out)], tmp_path,
                                lambda: out.exists() and any(out.iterdir()), env=proc_env)
    assert returncode == 130, err
    assert "Traceback" not in err and "error" not in err, err
    assert err.strip().splitlines()[-1] == "delaycomp: interrupted"
