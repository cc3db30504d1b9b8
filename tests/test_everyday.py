"""Everyday use (issue 19) and requests that cannot finish or outputs that mislead (issue 16,
items 7 and 9): output interval and streamed CSV, progress and verbosity, plots that explain
themselves, critical-delay with a new T, grids off the base grid, help and listing.

The CLI runs in this process (``cli.main``) with the in-process engine, which equals the
FMU run to the bit (tests/test_engines.py): the contract tested here is the command line's.
"""

from __future__ import annotations

import argparse
import csv
import math

import numpy as np
import pytest

from delaycomp import cli
from delaycomp.formats.outputs import CsvStream, OutputError, check_output
from delaycomp.maths.lti import lifted_loop
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.plotting import Timing, loop_title, result_figure
from delaycomp.studies import pool, sweep
from delaycomp.studies.axes import parse_grid, snap_axes

from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close

FAST = ["--engine", "inprocess"]


def run_cli(capsys, *args):
    code = cli.main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return rows[0], [[float(v) for v in row] for row in rows[1:]]


def one_line_error(code, err, message):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("delaycomp: error: ") and message in lines[0], err


# -- 1. output interval, CSV streamed ----------------------------------------------------

def test_output_interval_keeps_every_sth_row_of_the_full_run(tmp_path, capsys):
    full, thin = tmp_path / "full.csv", tmp_path / "thin.csv"
    assert run_cli(capsys, "run", "example-3.6", *FAST, "--out", str(full))[0] == 0
    code, out, _ = run_cli(capsys, "run", "example-3.6", *FAST, "--output-interval", "0.5",
                           "--out", str(thin))
    assert code == 0 and "41 rows to t = 20" in out
    head, rows = read_csv(full)
    head2, rows2 = read_csv(thin)
    assert head == head2
    # the same run, decimated: every 50th row of h = 0.01 (rows at 0, 0.5, ..., 20), the
    # same arithmetic, only fewer rows written (to the last bits)
    assert_columns_close(rows2, rows[::50], SAME_ARITHMETIC_ULPS, "decimated")
    assert [r[0] for r in rows2] == [0.5 * j for j in range(41)]


def test_stop_time_off_the_interval_still_ends_with_the_stop_time(tmp_path, capsys):
    out = tmp_path / "x.csv"
    code, _, _ = run_cli(capsys, "run", "example-3.6", *FAST, "--stop-time", "2.05",
                         "--output-interval", "1", "--out", str(out))
    assert code == 0
    assert [r[0] for r in read_csv(out)[1]] == [0.0, 1.0, 2.0, 2.05]


@pytest.mark.parametrize("value,message", [
    ("0.005", "--output-interval 0.005 is not allowed: must be a multiple of the base step"),
    ("0", "--output-interval 0.0 is not allowed: must be a finite number > 0"),
    ("nan", "--output-interval nan is not allowed"),
])
def test_bad_output_interval_is_one_line(capsys, value, message):
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--output-interval", value)
    one_line_error(code, err, message)


def test_streamed_run_keeps_one_row_in_memory_and_every_row_in_the_sink():
    sc = scenarios.get("example-3.6")
    spec = sc.make(sc.resolve([]))
    rows = []
    res = run_loop(spec, 20.0, engine="inprocess", every=10,
                   sink=lambda t, row: rows.append((t, *row)), keep=False)
    assert res.success and res.row_count == 201 and len(rows) == 201
    assert len(res.times) == 1 and res.times[0] == 20.0  # memory flat: only the last row
    full = run_loop(spec, 20.0, engine="inprocess")
    assert len(rows) == len(full.times[::10])
    assert_columns_close(rows, np.column_stack([full.times[::10], full.data[::10]]),
                         SAME_ARITHMETIC_ULPS, "streamed")


def test_csv_stream_is_renamed_only_when_complete(tmp_path):
    path = tmp_path / "s.csv"
    stream = CsvStream(path, ["plant.x"])
    stream(0.0, (1.0,))
    assert not path.exists() and stream.tmp.exists()  # written while running, as .part
    assert stream.finish(True) == path and path.exists() and not stream.tmp.exists()
    stream = CsvStream(path, ["plant.x"])
    stream(0.0, (1.0,))
    assert stream.finish(False).name == "s.csv.partial"


# -- issue 16.7: requests that cannot finish -----------------------------------------------

@pytest.mark.parametrize("args,message", [
    (["--stop-time", "1e12"], "this run needs 1e+14 base steps"),
    # the Python master's 40 us a step (the native core's 1.1 us a step and a row would
    # allow it, and the delay buffers' memory refuses it instead)
    (["--set", "N=1000000000", "--stepping", "python"], "this run needs 2e+10 base steps"),
], ids=["stop-time-1e12", "N-1e9"])
def test_run_that_cannot_finish_is_refused_with_an_estimate(capsys, tmp_path, args, message):
    out = tmp_path / "x.csv"
    code, _, err = run_cli(capsys, "run", "example-3.6", *args, "--out", str(out))
    one_line_error(code, err, message)
    assert "at least" in err and "over the limit of 24 hours" in err
    assert not list(tmp_path.iterdir())  # nothing started, nothing written


def test_grid_that_cannot_finish_is_refused_before_building_it(capsys, tmp_path):
    code, _, err = run_cli(capsys, "sweep", "example-3.6", "--grid", "r=0:0.5:100000",
                           "--grid", "k=0:1:100000", "--engine", "inprocess",
                           "--out", str(tmp_path / "s.csv"))
    one_line_error(code, err, "--grid: 1e+10 points at least")
    # the batch engine streams its rows to the CSV (its memory does not grow with the
    # grid), but resolving 1e11 points alone takes days, on any number of workers
    code, _, err = run_cli(capsys, "sweep", "example-3.6", "--grid", "r=0:0.5:100000",
                           "--grid", "k=0:1:100000", "--grid", "x0=1:2:10",
                           "--out", str(tmp_path / "s.csv"))
    one_line_error(code, err, "--grid: 1e+11 points at least")
    assert "days, over the limit of 24 hours" in err


def test_many_set_arguments_parse_in_linear_time(monkeypatch):
    """argparse matches the remaining arguments against a pattern at every option, so 60 000
    --set took minutes (quadratic). They are taken out in one pass: argparse does the same
    work for 60 000 --set as for one (counted in calls of its option parser, not in time)."""
    calls = []
    real = argparse.ArgumentParser._parse_optional
    monkeypatch.setattr(argparse.ArgumentParser, "_parse_optional",
                        lambda self, arg: calls.append(arg) or real(self, arg))
    sets, rest = cli._split_sets(["run", "example-3.6", *(["--set", "k=2"] * 60000),
                                  "--set=k=3", "--out", "x.csv"])
    assert len(sets) == 60001 and sets[-1] == "k=3" and rest == ["run", "example-3.6", "--out",
                                                                 "x.csv"]
    cli._parser().parse_args(rest)
    many = len(calls)
    calls.clear()
    cli._parser().parse_args(cli._split_sets(["run", "example-3.6", "--set", "k=2", "--out",
                                              "x.csv"])[1])
    assert many == len(calls)


def test_set_where_a_command_takes_none_is_one_line(capsys):
    code, _, err = run_cli(capsys, "list", "--set", "k=2")
    one_line_error(code, err, "delaycomp list takes no --set")


def test_sets_keep_their_order(capsys, tmp_path):
    out = tmp_path / "x.csv"
    code, _, _ = run_cli(capsys, "run", "example-3.6", *FAST, "--set", "k=5", "--stop-time",
                         "1", "--set=k=2", "--set", "u0=4", "--out", str(out))
    assert code == 0
    # the last k wins: with k = 2, u0 = 4 this is the start of Figure 3 (u(0) = -5.4986)
    assert abs(read_csv(out)[1][0][2] - (-5.498588075760031)) < 1e-12


# -- issue 16.9: outputs --------------------------------------------------------------------

def test_existing_folder_as_out_is_refused_before_running(capsys, tmp_path):
    folder = tmp_path / "x"
    folder.mkdir()
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--out", str(folder))
    one_line_error(code, err, "is a folder: give a file name")
    assert [p.name for p in tmp_path.iterdir()] == ["x"]  # no x.part beside it


@pytest.mark.parametrize("plot,message", [
    ("DIR/", "argument --plot: 'DIR/' is a folder"),
    ("fig.part", "the suffix must name a plot format"),
    ("fig.xyz", "the suffix must name a plot format"),
])
def test_bad_plot_path_is_one_line_before_running(capsys, tmp_path, plot, message):
    out = tmp_path / "x.csv"
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--out", str(out), "--plot",
                           str(tmp_path / plot) + ("/" if plot.endswith("/") else ""))
    one_line_error(code, err, message.replace("'DIR/'", repr(str(tmp_path / "DIR") + "/")))
    assert not out.exists()  # refused before the run: no CSV without its plot


def test_out_under_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        check_output(tmp_path / "f" / "x.csv", "--out")


def test_failed_rerun_leaves_no_older_result(capsys, tmp_path):
    out, png = tmp_path / "r.csv", tmp_path / "r.png"
    assert run_cli(capsys, "run", "example-3.6", *FAST, "--stop-time", "2", "--out",
                   str(out), "--plot", str(png))[0] == 0
    assert out.exists() and png.exists()
    # u = -1e300 x overflows at the first sample: the run fails
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--set", "k=1e300", "--set",
                           "mode=uncompensated", "--out", str(out), "--plot", str(png))
    assert code == 1 and "kept in" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv.partial"]


# -- 2. progress and verbosity --------------------------------------------------------------

def test_nothing_but_the_result_on_stdout_when_not_a_terminal(capsys, tmp_path):
    code, out, err = run_cli(capsys, "run", "proposition-4.2", *FAST, "--stop-time", "2")
    assert code == 0
    assert out.count("\n") == 1 and out.startswith("proposition-4.2: 201 rows to t = 2 ")
    assert "\r" not in err  # no bar when standard error is not a terminal (pytest's)


def test_quiet_and_verbose(capsys):
    sets = ["--set", "predictor=numerical", "--set", "p=sin"]
    code, _, err = run_cli(capsys, "run", "example-3.8", *FAST, "--stop-time", "1", *sets)
    assert code == 0
    code, _, quiet = run_cli(capsys, "run", "example-3.8", *FAST, "--stop-time", "1", "-q",
                             *sets)
    assert code == 0 and quiet == ""
    code, _, loud = run_cli(capsys, "run", "example-3.8", *FAST, "--stop-time", "1", "-v",
                            *sets)
    assert code == 0 and "100 base steps of h = 0.01 s" in loud and "estimated" in loud
    assert len(loud) > len(err)


def test_progress_ticks_once_per_point_as_points_finish_on_dask():
    import distributed  # the test extra brings it; no skip when it is missing
    jobs = [sweep.Job("example-3.6", (f"r={r}",), 2.0, "inprocess", None, True)
            for r in (0.1, 0.2, 0.3)]
    seen = []

    class Counting:
        def tick(self, count=1):
            seen.append(count)

    # dashboard on a free port: 8787 may be taken by another cluster on this machine
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        results = pool.on_dask(sweep.evaluate, jobs, cluster.scheduler_address, Counting())
    assert seen == [1, 1, 1]  # one tick per finished point, not one jump at the end
    assert results == [sweep.evaluate(j) for j in jobs]  # in grid order


# -- 3. plots ------------------------------------------------------------------------------

def test_plot_names_the_loop_marks_samples_and_the_first_delay_window():
    sc = scenarios.get("example-3.6")
    params = sc.resolve(["r=0.3", "tau=1"])
    spec = sc.make(params)
    res = run_loop(spec, 5.0, engine="inprocess")
    title = loop_title(sc.name, sc.title, params)
    fig = result_figure(res, title, Timing.of_spec(spec))
    try:
        assert fig._suptitle.get_text().startswith("example-3.6: Example 3.6")
        assert "T = 1 s, r = 0.3 s, tau = 1 s, compensated" in fig._suptitle.get_text()
        top = fig.axes[0]
        labels = [t.get_text() for t in top.get_legend().get_texts()]
        assert "plant.x" in labels and any("sampling instants" in t for t in labels)
        # the first exact prediction is at t_1 = 1 (ceil(r/T) = 1): window [1 - r, 1 + tau]
        spans = [p for p in top.patches if p.get_label().startswith("sample t_1")]
        assert len(spans) == 1
        x0, width = spans[0].get_x(), spans[0].get_width()  # a Rectangle, x in data
        assert math.isclose(x0, 0.7) and math.isclose(x0 + width, 2.0)
        assert fig.axes[-1].get_xlabel() == "time t [s]"
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def test_units_where_the_model_fixes_them(capsys, tmp_path):
    from delaycomp.plotting import UNITS_BY_LOOP

    sc = scenarios.get("proposition-4.2")
    spec = sc.make(sc.resolve([]))
    res = run_loop(spec, 2.0, engine="inprocess")
    fig = result_figure(res, "t", Timing.of_spec(spec), UNITS_BY_LOOP[sc.name])
    try:
        assert [a.get_ylabel() for a in fig.axes] == [
            "plant.x [m]", "plant.y [m]", "plant.theta [rad]", "controller.v [m/s]",
            "controller.omega [rad/s]"]
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def test_compare_draws_both_modes_of_the_same_loop(capsys, tmp_path):
    png = tmp_path / "both.png"
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--set", "r=0.5",
                             "--stop-time", "5", "--compare", "--plot", str(png))
    assert code == 0 and png.stat().st_size > 0, err
    sc = scenarios.get("example-3.6")
    runs = {m: run_loop(sc.make(sc.resolve(["r=0.5", f"mode={m}"])), 5.0,
                        engine="inprocess") for m in ("compensated", "uncompensated")}
    fig = result_figure(runs["compensated"], "t", compare=runs)
    try:
        labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert labels == ["plant.x, compensated", "plant.x, uncompensated"]
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def test_compare_needs_a_loop_with_a_mode(capsys, tmp_path):
    code, _, err = run_cli(capsys, "run", "example-2.4", *FAST, "--compare", "--plot",
                           str(tmp_path / "x.png"))
    one_line_error(code, err, "--compare needs a loop whose controller has a mode")


# -- 4. critical-delay with a new T ---------------------------------------------------------

@pytest.mark.fmu
def test_critical_delay_with_a_new_period_just_works(capsys):
    code, out, _ = run_cli(capsys, "critical-delay", "example-3.6", "--set", "k=1.9357",
                           "--set", "T=0.7157", "--periods", "20")
    assert code == 0, out
    r_c = float(out.splitlines()[0].split("=")[1])
    assert "T = 0.7157, tau = 0, k = 1.9357 held fixed" in out
    # r_c is where the exact lifted loop's spectral radius crosses 1 (Brent to 1e-12 in r;
    # rho is smooth there with slope O(1), so rho(r_c) = 1 to about 1e-9)
    rho = lifted_loop([[1.0]], [[1.0]], [[-1.9357]], 0.7157, r_c, 0.0,
                      "uncompensated").spectral_radius
    assert abs(rho - 1.0) < 1e-9


def test_critical_delay_says_what_was_held_fixed(capsys):
    code, _, err = run_cli(capsys, "critical-delay", "corollary-3.7")
    assert code == 1
    assert "unstable already at r = 0" in err and "T = 1, tau = 1, n = 3 held fixed" in err


# -- 5. grids off the base grid -------------------------------------------------------------

def test_grid_values_are_snapped_and_written_as_typed(capsys, tmp_path):
    out = tmp_path / "s.csv"
    code, _, err = run_cli(capsys, "sweep", "example-3.6", "--grid", "r=0:0.98:20",
                           "--exact", "--workers", "1", "--out", str(out))
    assert code == 0, err
    assert "r: 18 of 20 values snapped to the base grid h = T/N = 0.01" in err
    with open(out, newline="", encoding="utf-8") as fh:
        column = [row[0] for row in csv.reader(fh)][1:]
    assert column[:4] == ["0", "0.05", "0.1", "0.15"] and column[-1] == "0.98"
    # every written value is a whole multiple of h = 0.01
    assert all(abs(float(v) / 0.01 - round(float(v) / 0.01)) < 1e-9 for v in column)


def test_grid_values_off_linspace_roundoff():
    assert parse_grid("k=0:0.3:7").values == (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3)


def test_no_snapping_when_the_base_step_itself_is_swept():
    axes = [parse_grid("T=0.5:1:3"), parse_grid("r=0:0.98:20")]
    assert snap_axes("example-3.6", axes, []) == (axes, [])


# -- 6. help and listing --------------------------------------------------------------------

def _subparsers():
    parser = cli._parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


@pytest.mark.parametrize("command", list(_subparsers()))
def test_every_option_and_argument_has_help(command):
    parser = _subparsers()[command]
    missing = [a.dest for a in parser._actions if not a.help]
    assert missing == []


def test_run_help_shows_examples(capsys):
    with pytest.raises(SystemExit):
        cli.main(["run", "--help"])
    out = capsys.readouterr().out
    assert "examples:" in out and "--output-interval 1" in out


def test_list_fits_100_columns_and_aligns(capsys):
    code, out, _ = run_cli(capsys, "list")
    assert code == 0
    lines = out.splitlines()
    assert max(len(line) for line in lines) <= 100
    rows = [line for line in lines if line.startswith("    ") and not line.startswith(" " * 5)]
    assert len(rows) > 40
    # a parameter row: name in columns 4-13, default from 14, the text from column 30
    for line in rows:
        assert line[13] == " " and line[14] != " ", line
        assert line[29] == " " and line[30] != " ", line
