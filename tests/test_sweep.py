"""Sweeps and stability maps: grid parsing, metrics, exact maps, engines, mismatch."""

from __future__ import annotations

import csv
import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from delaycomp.maths.lti import lifted_loop
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper.scenarios import ParameterError, lti_loop
from delaycomp.studies import sweep
from delaycomp.studies.axes import parse_grid
from delaycomp.studies.critical import fitted_spectral_radius
from delaycomp.studies.sweep import SweepOptions

from .conftest import REPO
from .roundoff import SAME_ARITHMETIC_ULPS, assert_same_values


def test_parse_grid():
    axis = parse_grid("r=0:0.4:5")
    assert axis.name == "r" and axis.values == pytest.approx((0.0, 0.1, 0.2, 0.3, 0.4))
    assert parse_grid("T=1:2:1").values == (1.0,)


@pytest.mark.parametrize("text", ["r", "r=0:1", "r=a:1:3", "r=0:1:0", "r=0:inf:3", "=0:1:2"])
def test_parse_grid_rejects(text):
    with pytest.raises(ParameterError, match="--grid"):
        parse_grid(text)


def synthetic(rho, periods=20, N=10, phase=True):
    t = np.arange(periods * N + 1) / N
    x = rho ** t * (np.cos(2.1 * t) if phase else 1.0)
    return t, x[:, None]


@pytest.mark.parametrize("rho", [0.5, 0.9, 1.0, 1.1])
def test_metrics_recover_a_known_rate(rho):
    t, x = synthetic(rho)
    m = sweep.metrics_of(t, x, 10, True)
    # an oscillating geometric sequence: the root-sum-square per period removes most of the
    # phase; 2 % is the estimator's budget over 16 periods
    assert m["rho"] == pytest.approx(rho, rel=0.02)
    assert m["stable"] == int(m["rho"] < 1)
    assert m["peak_norm"] == pytest.approx(np.abs(x).max())
    assert m["final_norm"] == pytest.approx(abs(x[-1, 0]))


def test_metrics_deadbeat_and_failure():
    t = np.arange(101) / 10
    x = np.where(t < 3.0, 1.0, 1e-14)[:, None]
    m = sweep.metrics_of(t, x, 10, True)
    assert m["deadbeat_time"] == pytest.approx(3.0) and m["stable"] == 1
    assert m["failed"] == ""
    # the loop diverged (one of our components said so): unstable, with its reason
    m = sweep.metrics_of(t, np.ones((101, 1)), 10, False, "plant diverged", diverged=True)
    assert m["rho"] == math.inf and m["stable"] == 0 and m["deadbeat_time"] is None
    assert m["failed"] == "plant diverged"
    # any other failure: neither stable nor unstable
    m = sweep.metrics_of(t, np.ones((101, 1)), 10, False, "plant: x = nan\nat t = 1")
    assert m["rho"] is None and m["stable"] is None and m["failed"] == "plant: x = nan at t = 1"
    # a trajectory that turned NaN in a run that reported success (a master that ran on)
    x = np.ones((101, 1))
    x[57:] = np.nan
    m = sweep.metrics_of(t, x, 10, True)
    assert m["stable"] is None and m["failed"] == "the plant state is not finite at t = 5.7"
    assert m["peak_norm"] == 1.0 and math.isnan(m["final_norm"])


@pytest.mark.fmu
def test_exact_map_agrees_with_simulation(fmu_dir):
    """--exact (lifted model) against the rate estimated from 20 simulated periods: the
    estimator's error on this loop is below 0.02 (measured <= 0.017)."""
    axes = [parse_grid("r=0.05:0.35:4")]
    sets = ["mode=uncompensated"]
    sim = sweep.run_sweep("example-3.6", axes, sets, SweepOptions(fmu_dir=str(fmu_dir)))
    exact = sweep.run_sweep("example-3.6", axes, sets, SweepOptions(exact=True))
    for s, e in zip(sim, exact):
        assert s["rho"] == pytest.approx(e["rho"], abs=0.02)
        if abs(e["rho"] - 1) > 0.02:
            assert s["stable"] == e["stable"]


@pytest.mark.fmu
def test_results_do_not_depend_on_workers_or_dask(fmu_dir):
    from distributed import LocalCluster

    axes = [parse_grid("r=0.1:0.3:3")]
    options = SweepOptions(stop=5.0, fmu_dir=str(fmu_dir))

    def rows(**changes):
        return sweep.run_sweep("example-3.6", axes, ["mode=uncompensated"],
                               dataclasses.replace(options, **changes))

    serial = rows()
    procs = rows(workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        dask_rows = rows(scheduler=cluster.scheduler_address)
    # other processes, the same arithmetic: the same rows to the last bits
    assert_same_values(procs, serial, SAME_ARITHMETIC_ULPS, "workers")
    assert_same_values(dask_rows, serial, SAME_ARITHMETIC_ULPS, "dask")


def test_invalid_grid_point_is_named_before_anything_runs():
    with pytest.raises(ParameterError, match=r"grid point r=0\.105: .*multiple of the base"):
        sweep.run_sweep("example-3.6", [parse_grid("r=0.1:0.11:3")], [])


@pytest.mark.fmu
@pytest.mark.parametrize("r_true,tau_true", [(0.4, 0.0), (0.3, 0.05), (0.25, 0.2)])
def test_mismatch_lifted_model_is_exact(fmu_dir, r_true, tau_true):
    """Controller assumes r = 0.3, tau = 0; the loop has other delays (on the base grid).
    The co-simulated samples obey the mismatched lifted model to round-off."""
    T, N, r = 1.0, 20, 0.3
    A, B, K = [[1.0]], [[1.0]], [[-2.0]]
    spec = lti_loop(A, B, K, T, r, 0.0, N, "compensated", [1.0], [0.4], r_true=r_true,
                    tau_true=tau_true)
    res = run_loop(spec, 25.0, fmu_dir)
    loop = lifted_loop(A, B, K, T, r, 0.0, "compensated", r_true, tau_true)
    assert fitted_spectral_radius(res, 1, 1, T, N, r_true, loop.L) == pytest.approx(
        loop.spectral_radius, rel=1e-6)


def test_mismatch_changes_stability_and_none_is_the_matched_loop():
    matched = lifted_loop([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.3, 0.0, "compensated")
    same = lifted_loop([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.3, 0.0, "compensated", 0.3, 0.0)
    assert matched.spectral_radius == pytest.approx(same.spectral_radius, rel=1e-14)
    assert matched.spectral_radius == pytest.approx(math.e - 2, rel=1e-10)
    off = lifted_loop([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.3, 0.0, "compensated", 0.6, 0.0)
    assert off.spectral_radius > 1.0  # far enough off, compensation no longer holds


def cli(*args):
    return subprocess.run([sys.executable, "-m", "delaycomp.cli", *args], capture_output=True,
                          text=True, cwd=REPO, timeout=600)


def test_sweep_cli_exact_heat_map(tmp_path):
    out, png = tmp_path / "map.csv", tmp_path / "map.png"
    proc = cli("sweep", "example-3.6", "--grid", "r_true=0:0.6:7", "--grid", "r=0:0.6:7",
               "--set", "mode=compensated", "--exact", "--out", str(out), "--plot", str(png))
    assert proc.returncode == 0, proc.stderr
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["r_true", "r", "rho", "stable", "final_norm", "peak_norm",
                       "deadbeat_time", "failed"]
    assert len(rows) == 1 + 49
    assert all(row[-1] == "" for row in rows[1:])  # --exact: nothing runs, nothing fails
    diag = [row for row in rows[1:] if row[0] == row[1]]
    assert all(float(row[2]) == pytest.approx(math.e - 2, rel=1e-9) for row in diag)
    assert png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("args,message", [
    (["sweep", "example-3.6", "--grid", "r=0:1", "--out", "x.csv"], "--grid"),
    (["sweep", "example-3.6", "--grid", "k=1:3:3", "--exact", "--workers", "0", "--out",
      "x.csv"], "--workers 0"),
    (["sweep", "example-2.4", "--grid", "T=1:2:2", "--exact", "--out", "x.csv"],
     "--exact needs an LTI scenario"),
])
def test_sweep_cli_errors(args, message):
    proc = cli(*args)
    assert proc.returncode == 2
    assert message in proc.stderr and proc.stderr.count("\n") == 1
    assert "Traceback" not in proc.stderr


def test_critical_delay_grid_table():
    proc = cli("critical-delay", "example-3.6", "--grid", "T=0.5:1.5:3")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert "0.361350615" in lines[1] and "stable" in lines[1]
    assert "0.203267055" in lines[2]
    assert "unstable at r=0" in lines[3]  # T = 1.5 violates (3.20): T < ln 3


@pytest.mark.parametrize("engine", ["batch", "inprocess", "fmu"])
def test_a_sweep_reads_its_loop_file_once(tmp_path, monkeypatch, fmu_dir, engine):
    """``delaycomp sweep LOOP.toml`` reads the file once, whatever the engine: the opened
    loop is handed down to the checks, the snapping, the validation and every point's
    job (a worker process gets its data with the job, not the path to read again)."""
    from delaycomp.cli import main
    from delaycomp.paper.scenarios import loop_file
    from delaycomp.system.loopfile import LoopFile

    loop = tmp_path / "loop.toml"
    loop.write_text(loop_file("example-3.6").read_text())
    reads = []
    read = LoopFile.__init__

    def counted(self, path):
        reads.append(Path(path).name)
        read(self, path)

    monkeypatch.setattr(LoopFile, "__init__", counted)
    code = main(["sweep", str(loop), "--grid", "r=0:0.2:3", "--stop-time", "4",
                 "--engine", engine, "--workers", "1", "--fmu-dir", str(fmu_dir),
                 "--out", str(tmp_path / "rows.csv"), "-q"])
    assert code == 0
    assert reads == ["loop.toml"]
    assert len((tmp_path / "rows.csv").read_text().splitlines()) == 4  # a header, 3 points
