"""A misbehaving plant FMU is contained (issue 30, item 2).

Another tool's FMU file runs in a child process (``delaycomp.orchestrator.isolated``):
a ``doStep`` that never returns is stopped by the watchdog, Ctrl-C ends the command while
it hangs, an FMU that calls ``exit()`` or crashes fails the run instead of ending the
command (before: a hang was for ever and deaf to Ctrl-C; ``exit(0)`` made ``run`` exit 0
with no result). A modelDescription whose output has an input's value reference, or that
declares a name twice, is refused when the FMU is opened.

Which of these need the child process: the watchdog (a C call cannot be interrupted in
the process that made it), Ctrl-C during the call (a signal reaches Python only between
bytecodes) and ``exit()`` / a crash (they end the process they happen in). The
declarations are checked without running the FMU at all.
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

import numpy as np
import pytest

from .test_broken_plant import LOOP

pytestmark = pytest.mark.fmu


def _cli(*args, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def _children_of_fmu(folder: Path) -> list[int]:
    """Processes still running with ``folder`` on their command line (the FMU's child)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if str(folder) in cmd and "delaycomp.orchestrator.isolated" in cmd:
            found.append(int(entry.name))
    return found


@pytest.fixture
def plant(tmp_path, request):
    """A loop whose plant FMU misbehaves as ``request.param`` from t = 1."""
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Broken.fmu", misbehave=request.param, after=1.0)
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    yield tmp_path
    for pid in _children_of_fmu(tmp_path):  # a failing test leaves nothing running
        os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("plant", ["hang"], indirect=True)
def test_a_step_that_never_returns_is_stopped_by_the_watchdog(plant):
    started = time.monotonic()
    proc = _cli("run", "loop.toml", "--watchdog", "1", "--out", "out.csv", cwd=plant)
    elapsed = time.monotonic() - started
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith(
        "delaycomp: error: plant failed at t = 1: fmi2DoStep from t = 1 did not return "
        "within 1 s: the FMU is stopped (the watchdog; --watchdog SECONDS sets it)")
    rows = (plant / "out.csv.partial").read_text().splitlines()
    assert len(rows) == 2 + round(1.0 / 0.05)  # the header, then t = 0 .. 1 (its step hung)
    assert elapsed < 30  # 1 s of watchdog, two interpreters' start, the FMU's builds
    assert _children_of_fmu(plant) == []


@pytest.mark.alone  # the interrupt must end the command within a second
@pytest.mark.parametrize("plant", ["hang"], indirect=True)
def test_ctrl_c_ends_the_command_while_a_step_hangs(plant):
    """SIGINT to the process group, as a terminal sends it, with the default watchdog
    (10 s) far away: exit 130 within a second, the child gone."""
    proc = subprocess.Popen([sys.executable, "-m", "delaycomp", "run", "loop.toml",
                             "--out", "out.csv"], cwd=plant, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not (plant / "out.csv.part").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.5)  # the run reaches t = 1 in well under a second, then hangs
        assert proc.poll() is None, proc.communicate()
        sent = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        waited = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, out + err
    # the step from t = 1 hangs: the time reached is 1 (the row of t = 1 is the last)
    assert err.strip().splitlines()[-1] == "delaycomp: interrupted at t = 1"
    assert "Traceback" not in err
    assert waited < 1.0
    assert _children_of_fmu(plant) == []


@pytest.mark.parametrize("plant,why", [("exit", "exit status 0: it called exit()"),
                                       ("crash", "killed by signal SIGSEGV")],
                         indirect=["plant"])
def test_an_fmu_that_ends_its_process_fails_the_run(plant, why):
    proc = _cli("run", "loop.toml", "--out", "out.csv", cwd=plant)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith(
        f"delaycomp: error: plant failed at t = 1: the FMU ended its process during "
        f"fmi2DoStep from t = 1 ({why})")
    assert not (plant / "out.csv").exists()
    assert (plant / "out.csv.partial").exists()


@pytest.mark.parametrize("plant", ["exit"], indirect=True)
def test_the_api_raises_and_a_sweep_marks_the_points_failed(plant):
    from delaycomp import api
    from delaycomp.errors import SimulationFailed

    with pytest.raises(SimulationFailed, match=r"it called exit\(\)"):
        api.run(api.load(plant / "loop.toml"), watchdog=5)
    rows = api.sweep(plant / "loop.toml", {"r": [0.2, 0.3]}, engine="fmu")
    assert all(r["stable"] is None and "it called exit()" in r["failed"] for r in rows)


def test_a_healthy_fmu_file_in_its_child_gives_the_same_numbers(tmp_path, monkeypatch):
    """The child process changes nothing: the run equals the FMU loaded in this process,
    bit for bit (the same library, the same calls in the same order)."""
    from delaycomp import api
    from delaycomp.orchestrator import isolated
    from delaycomp.orchestrator.fmu import FmuComponent
    from tests.cfmu.build import build_oscillator

    build_oscillator(tmp_path, "Broken.fmu")
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    loop = api.load(tmp_path / "loop.toml")
    apart = api.run(loop, 10.0, fmus="python")

    class InProcess(FmuComponent):
        def __init__(self, name, path, watchdog):
            super().__init__(name, path)

    monkeypatch.setattr(isolated, "IsolatedFmu", InProcess)
    here = api.run(loop, 10.0, fmus="python")
    assert np.array_equal(apart.data, here.data) and apart.names == here.names
    assert len(apart.times) == 201


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf"])
def test_a_bad_watchdog_is_refused_in_one_line(tmp_path, value):
    proc = _cli("run", "example-3.6", "--stop-time", "1", f"--watchdog={value}", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (f"delaycomp: error: --watchdog {float(value)!r} is not "
                                   "allowed: must be a finite number of seconds > 0")


def test_the_default_watchdog_follows_the_loop():
    from delaycomp.orchestrator.isolated import default_watchdog

    assert default_watchdog(0.05) == 10.0  # the floor
    assert default_watchdog(0.5) == 50.0  # 100 base steps
    assert default_watchdog(600.0) == 60000.0


# -- declarations that cannot hold -------------------------------------------------------------

def _rewrite(fmu: Path, edit) -> None:
    """Rewrite ``fmu``'s modelDescription.xml through ``edit(text) -> text``."""
    with zipfile.ZipFile(fmu) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    text = edit(members["modelDescription.xml"].decode())
    members["modelDescription.xml"] = text.encode()
    with zipfile.ZipFile(fmu, "w") as zf:
        for n, data in members.items():
            zf.writestr(n, data)


@pytest.mark.parametrize("edit,message", [
    (lambda t: t.replace('name="acceleration" valueReference="3"',
                         'name="acceleration" valueReference="4"'),
     "declares output 'acceleration' with the value reference 4 of input 'force' (Real): "
     "an input may share its value reference with no other variable"),
    (lambda t: t.replace('name="velocity" valueReference="1"',
                         'name="position" valueReference="1"'),
     "declares the variable 'position' twice (ScalarVariables 1 and 2): names must be "
     "unique"),
    (lambda t: t.replace('name="velocity" valueReference="1"',
                         'name="velocity" valueReference="-1"'),
     "declares 'velocity' with valueReference = '-1': must be an integer from 0 to "
     "4294967295"),
])
def test_declarations_that_cannot_hold_are_refused_when_the_fmu_is_opened(tmp_path, edit,
                                                                           message):
    from tests.cfmu.build import build_oscillator

    fmu = build_oscillator(tmp_path, "Broken.fmu")
    _rewrite(fmu, edit)
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    proc = _cli("run", "loop.toml", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip() == f"delaycomp: error: {fmu.resolve()}: {message}" or \
        re.fullmatch(rf"delaycomp: error: \S*Broken\.fmu: {re.escape(message)}",
                     proc.stderr.strip()), proc.stderr


def test_aliases_among_outputs_and_locals_pass(tmp_path):
    """FMI 2.0's own aliases (an output and a local sharing a value reference) are not
    refused: the run goes on as with the FMU as built."""
    from tests.cfmu.build import build_oscillator

    fmu = build_oscillator(tmp_path, "Broken.fmu")
    _rewrite(fmu, lambda t: t.replace('name="der(position)" valueReference="2"',
                                      'name="der(position)" valueReference="1"'))
    (tmp_path / "loop.toml").write_text(LOOP, encoding="utf-8")
    proc = _cli("run", "loop.toml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
