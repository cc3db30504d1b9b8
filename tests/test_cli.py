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
    (["run", "example-3.6", "--set", "tau=0.5"],
     "tau = 0.5 is not allowed: zero-order hold needs a multiple l*T"),
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


# the same command's FMUs and archives are checked in the fast tier, native and run, by
# tests/test_native_default.py::test_build_writes_native_fmus_and_archives_by_default
@pytest.mark.slow
def test_build_writes_three_valid_fmus_and_an_ssp_per_scenario(tmp_path):
    from delaycomp.paper.scenarios import SCENARIOS

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


def test_list_says_which_delays_lie_on_the_base_grid():
    """``list`` states the grid rule the checks enforce: ``r`` (and the true delays) a
    whole number of base steps everywhere; ``tau`` a multiple of ``T`` under zero-order
    hold (base steps with ``pad=1``), base steps under continuous input."""
    from delaycomp.paper.scenarios import ON_BASE_GRID, SCENARIOS, ZOH_TAU_PAD

    proc = cli("list")
    assert proc.returncode == 0
    assert max(len(line) for line in proc.stdout.splitlines()) <= 100
    blocks = {b.split(":", 1)[0]: " ".join(b.split()) for b in proc.stdout.split("\n\n")}
    assert blocks.keys() == SCENARIOS.keys()
    tau = {"example-3.6": ZOH_TAU_PAD, "corollary-3.7": ZOH_TAU_PAD,  # the LTI loop pads too
           "example-3.8": ZOH_TAU_PAD, "proposition-4.2": ZOH_TAU_PAD,
           "example-2.4": ON_BASE_GRID, "corollary-4.1": ON_BASE_GRID}
    assert ON_BASE_GRID == "a finite number >= 0, a whole number of base steps h = T/N"
    for name, text in blocks.items():
        assert f"measurement delay; {ON_BASE_GRID} tau " in text, name
        assert f"input delay; {tau[name]} N " in text, name
        for true in ("r_true (= r)", "tau_true (= tau)"):
            start = text.index(true)
            assert ON_BASE_GRID in text[start:start + 200], (name, true)


@pytest.mark.parametrize("name", ["example-3.6", "example-2.4", "example-3.8",
                                  "corollary-3.7", "corollary-4.1", "proposition-4.2"])
def test_what_list_allows_for_r_and_tau_is_what_is_accepted(name):
    """The allowed-range text of ``r`` and ``tau`` is true: an off-grid value is refused
    exactly where the text says so, and the refusal names the rule."""
    from delaycomp.errors import ParameterError
    from delaycomp.paper import scenarios

    sc = scenarios.get(name)
    T, N = sc.param("T").default, sc.param("N").default
    h = T / N
    assert sc.param("r").allowed == scenarios.ON_BASE_GRID
    sc.resolve([f"r={7 * h!r}"])
    with pytest.raises(ParameterError, match="must be a multiple of the base step h = T/N"):
        sc.resolve([f"r={7.5 * h!r}"])
    with pytest.raises(ParameterError, match="whole number of base steps"):
        sc.resolve(["r=-1"])          # the parse-time message is the list's text
    allowed = sc.param("tau").allowed
    has_pad = any(p.name == "pad" for p in sc.params)
    half = [f"tau={T / 2!r}"]          # on the base grid (N even), not a multiple of T
    with pytest.raises(ParameterError, match=r"tau = .* is not allowed"):  # off any grid
        sc.resolve([f"tau={T + 0.5 * h!r}", *(["pad=1"] if has_pad else [])])
    if allowed == scenarios.ON_BASE_GRID:
        sc.resolve(half)
    else:
        assert allowed.startswith(scenarios.ZOH_TAU)
        with pytest.raises(ParameterError, match="multiple l\\*T") as exc:
            sc.resolve(half)
        # the pad hint only where the scenario has pad, and pad=1 then takes the half period
        assert ("pad = true" in str(exc.value)) == has_pad == ("pad=1" in allowed)
        if has_pad:
            sc.resolve([*half, "pad=1"])
