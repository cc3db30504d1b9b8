"""A CLI that answers at once: what only reads its arguments, prints help or lists the
scenarios imports neither scipy nor matplotlib nor fmpy (nor lxml, pythonfmu).

Not a timed test (speed is measured in ``bench/``): a fresh interpreter runs the command
through :func:`delaycomp.cli.main` and reports which of those packages ``sys.modules``
holds at its end. Importing scipy alone cost ``delaycomp --help`` about 0.35 s of its
0.45 s on a 2-core machine (``python -X importtime``)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: what a command that does no maths, runs no FMU and writes no SSP must not import
HEAVY = ("scipy", "matplotlib", "fmpy", "lxml", "pythonfmu")

PROBE = """
import contextlib, io, json, sys
from delaycomp import cli
with contextlib.redirect_stdout(io.StringIO()) as out, \\
        contextlib.redirect_stderr(io.StringIO()) as err:
    try:
        code = cli.main(sys.argv[1:])
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"code": code, "out": out.getvalue(), "err": err.getvalue(),
                  "modules": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def run_probe(*argv: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


LIGHT = [
    (["--help"], 0, "usage: delaycomp"),
    (["--version"], 0, "delaycomp"),
    (["list"], 0, "example-3.6"),
    (["run", "--help"], 0, "usage: delaycomp run"),
    (["run", "example-3.6", "--no-such-flag"], 2, "unrecognized arguments"),
    (["run", "example-9.9"], 2, "unknown scenario 'example-9.9'"),
    (["run", "example-3.6", "--set", "r=0.305"], 2, "r = 0.305 is not allowed"),
    (["run", "example-3.6", "--set", "k=abc"], 2, "k = 'abc' is not allowed"),
    (["sweep", "example-3.6", "--grid", "r=bad", "--out", "x.csv"], 2,
     "expected NAME=START:STOP:COUNT"),
    (["critical-delay", "example-9.9"], 2, "unknown scenario"),
    (["check", "--case", "example-9.9/x"], 2, "example-9.9/x"),
    (["ssp", "example-9.9", "--out", "x.ssp"], 2, "unknown scenario"),
]


@pytest.mark.parametrize("argv,code,text", LIGHT, ids=[" ".join(a) for a, _, _ in LIGHT])
def test_help_list_and_argument_errors_import_no_heavy_package(argv, code, text):
    res = run_probe(*argv)
    assert res["code"] == code, res
    assert text in res["out"] + res["err"], res
    heavy = sorted(set(HEAVY) & set(res["modules"]))
    assert not heavy, f"delaycomp {' '.join(argv)} imported {heavy}"


def test_the_probe_sees_an_import_when_there_is_one():
    """Not vacuous: a command that does the maths (``critical-delay``) does import scipy."""
    res = run_probe("critical-delay", "example-3.6", "--periods", "10")
    assert res["code"] in (0, 1), res
    assert "scipy" in res["modules"]
