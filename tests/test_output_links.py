"""Outputs never written through links (issue 30, item 6).

Every output file is written to a new file beside it and renamed into place
(``delaycomp.tmpfiles.replacing``): a link at the output's name, or at its working
name (``FILE.part``), is replaced, and its target is never opened. A FIFO, a device or a
socket as an output is refused before anything runs, in one line, exit 2. Before:
``export-loop --out`` followed a link and overwrote its target (and was not atomic), and
``run --out`` wrote through a link at ``FILE.part``.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

KEEP = "the link's target: must be left alone\n"


def _cli(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "delaycomp", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def _linked(folder: Path, name: str) -> Path:
    """``folder/name`` as a link to a file holding ``KEEP``; return the target."""
    target = folder / f"target-of-{name.replace('/', '-')}"
    target.write_text(KEEP, encoding="utf-8")
    (folder / name).symlink_to(target)
    return target


#: (arguments, the outputs they write, beside a link each)
COMMANDS = {
    "run": (["run", "example-3.6", "--engine", "inprocess", "--stop-time", "2",
             "--out", "o.csv", "--plot", "o.png"], ["o.csv", "o.png"]),
    "run-part": (["run", "example-3.6", "--engine", "inprocess", "--stop-time", "2",
                  "--out", "o.csv"], ["o.csv.part"]),
    "sweep": (["sweep", "example-3.6", "--grid", "k=1:2:2", "--stop-time", "2",
               "--out", "s.csv"], ["s.csv"]),
    "critical-delay": (["critical-delay", "example-3.6", "--grid", "k=1:2:2",
                        "--out", "c.csv", "--plot", "c.png"], ["c.csv", "c.png"]),
    "export-loop": (["export-loop", "example-3.6", "--python", "--out", "loop.fmu"],
                    ["loop.fmu"]),
    "ssp": (["ssp", "example-3.6", "--python", "--out", "loop.ssp"], ["loop.ssp"]),
    "export-c": (["export-c", "example-3.6", "--prefix", "ctl", "--out", "c"],
                 ["c/ctl.c", "c/ctl.h"]),
    "build": (["build", "example-3.6", "--python", "--only", "controller", "--out", "b"],
              ["b/example-3.6_wiring.txt"]),
}


@pytest.mark.fmu
@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_link_at_an_output_is_replaced_and_its_target_left_alone(tmp_path, command):
    args, outputs = COMMANDS[command]
    for out in outputs:
        (tmp_path / out).parent.mkdir(parents=True, exist_ok=True)
    targets = {out: _linked(tmp_path, out) for out in outputs}
    proc = _cli(*args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for out, target in targets.items():
        assert target.read_text(encoding="utf-8") == KEEP, out
        if out.endswith(".part"):  # the working file: renamed into place, no link left
            assert not (tmp_path / out).exists() and not (tmp_path / out).is_symlink()
        else:
            assert not (tmp_path / out).is_symlink() and (tmp_path / out).stat().st_size
    assert not list(tmp_path.rglob(".*.part*"))  # no working file left behind


def _fifo(folder: Path) -> str:
    os.mkfifo(folder / "fifo")
    return "fifo"


def _socket(folder: Path) -> str:
    with socket.socket(socket.AF_UNIX) as sock:  # the name stays after the socket closes
        sock.bind(str(folder / "sock"))
    return "sock"


def _device(folder: Path) -> str:
    """A character device: a null device of our own where we may make one (as root, who
    could also replace /dev/null itself were the refusal to fail: the code before it did
    exactly that), else /dev/null (whose folder others cannot write to)."""
    import stat

    try:
        os.mknod(folder / "null", stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        return "/dev/null"
    return "null"


@pytest.mark.parametrize("make,what", [(_fifo, "a FIFO"), (_device, "a device"),
                                       (_socket, "a socket")])
@pytest.mark.parametrize("option", ["--out", "--plot"])
def test_a_fifo_device_or_socket_as_output_is_refused_in_one_line(tmp_path, make, what,
                                                                   option):
    name = make(tmp_path)
    if option == "--plot" and not name.endswith(".png"):
        link = tmp_path / "x.png"  # a plot needs a plot suffix: a link of that name
        link.symlink_to(tmp_path / name if not name.startswith("/") else name)
        name, what = "x.png", None  # a link is replaced, not refused: the run goes on
    proc = _cli("run", "example-3.6", "--engine", "inprocess", "--stop-time", "1", option,
                name, cwd=tmp_path)
    if what is None:
        assert proc.returncode == 0, proc.stderr
        return
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip() == (f"delaycomp: error: {option} {name!r} is not allowed: it "
                                   f"is {what}, not a regular file (results are written to "
                                   "a new file and renamed into place)")


def test_export_loop_and_ssp_refuse_a_fifo(tmp_path):
    os.mkfifo(tmp_path / "loop.fmu")
    os.mkfifo(tmp_path / "loop.ssp")
    for args in (["export-loop", "example-3.6", "--out", "loop.fmu"],
                 ["ssp", "example-3.6", "--out", "loop.ssp"]):
        proc = _cli(*args, cwd=tmp_path)
        assert proc.returncode == 2, proc.stdout + proc.stderr
        assert "is a FIFO, not a regular file" in proc.stderr
