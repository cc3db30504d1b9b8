"""``run --compare`` (issue 27, item 3: the first command shows the point): both runs'
data (this run in ``--out``, the other mode's beside it), both runs drawn on a scale on
which both read, said on the figure.

The CLI runs in this process (``cli.main``) with the in-process engine, which equals the
FMU run to the bit (tests/test_engines.py): the contract tested here is the command
line's and the figure's.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.plotting import (
    LINEAR_RATIO,
    Scale,
    choose_scale,
    figure,
    panel_scales,
    result_figure,
)

from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close
from .test_everyday import FAST, one_line_error, read_csv, run_cli

REPO = Path(__file__).resolve().parents[1]


def _close(fig):
    import matplotlib.pyplot as plt

    plt.close(fig)


# -- 1. --compare writes both runs' data ---------------------------------------------------

def test_compare_out_keeps_this_run_and_writes_the_other_beside_it(capsys, tmp_path):
    """``--out FILE.csv`` holds this run exactly as without ``--compare``; the other
    mode goes to ``FILE.uncompensated.csv``, equal to a run of that mode on its own, with
    the same columns and row times; no ``--plot`` needed."""
    both = tmp_path / "example-3.6.csv"
    code, out, err = run_cli(capsys, "run", "example-3.6", *FAST, "--set", "r=0.3",
                             "--set", "u0=4", "--compare", "--out", str(both))
    assert code == 0, err
    other = tmp_path / "example-3.6.uncompensated.csv"
    assert f"example-3.6, uncompensated: 2001 rows in {other}" in out
    alone = {}
    for mode in ("compensated", "uncompensated"):
        alone[mode] = tmp_path / f"alone-{mode}.csv"
        assert run_cli(capsys, "run", "example-3.6", *FAST, "--set", "r=0.3", "--set",
                       "u0=4", "--set", f"mode={mode}", "--out", str(alone[mode]))[0] == 0
    head, rows = read_csv(both)
    head_other, rows_other = read_csv(other)
    assert head == head_other == ["time", "plant.x", "controller.u"]
    assert [r[0] for r in rows] == [r[0] for r in rows_other]
    # the same runs, the same arithmetic: equal to the last bits
    assert_columns_close(rows, read_csv(alone["compensated"])[1], SAME_ARITHMETIC_ULPS,
                         "compensated")
    assert_columns_close(rows_other, read_csv(alone["uncompensated"])[1],
                         SAME_ARITHMETIC_ULPS, "uncompensated")
    # and they differ: the uncompensated loop of r = 0.3 > r_c grows
    assert abs(rows_other[-1][1]) > 10 * abs(rows[-1][1])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [both.name, other.name, "alone-compensated.csv", "alone-uncompensated.csv"])


def test_compare_of_an_uncompensated_run_writes_the_compensated_beside(capsys, tmp_path):
    out = tmp_path / "u.csv"
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--set",
                           "mode=uncompensated", "--stop-time", "3", "--compare", "--out",
                           str(out))
    assert code == 0, err
    assert read_csv(out)[1][0][2] == -2.0                     # u = -k x0 = -2
    assert read_csv(tmp_path / "u.compensated.csv")[1][0][2] != -2.0  # predicted


def test_compare_rows_follow_the_output_interval(capsys, tmp_path):
    out = tmp_path / "x.csv"
    assert run_cli(capsys, "run", "example-3.6", *FAST, "--stop-time", "2.05", "--compare",
                   "--output-interval", "1", "--out", str(out))[0] == 0
    for path in (out, tmp_path / "x.uncompensated.csv"):
        assert [r[0] for r in read_csv(path)[1]] == [0.0, 1.0, 2.0, 2.05]


def test_compare_needs_out_or_plot(capsys):
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--compare")
    one_line_error(code, err, "--compare writes both runs: give --out FILE.csv")


def test_the_other_csv_is_checked_before_anything_runs(capsys, tmp_path):
    (tmp_path / "x.uncompensated.csv").mkdir()
    out = tmp_path / "x.csv"
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--compare", "--out",
                           str(out))
    one_line_error(code, err, "--out (--compare) ")
    assert "x.uncompensated.csv' is a folder" in err
    assert not out.exists()


def test_a_failed_other_run_keeps_its_rows_apart_and_draws_nothing(capsys, tmp_path):
    """The uncompensated loop of k = 2.1, r = 0.9 overflows before t = 1200 while the
    compensated one converges: this run's CSV is complete, the other's rows are in its
    ``.partial``, no plot, exit 1, and an older result at either path is gone."""
    out, png = tmp_path / "x.csv", tmp_path / "x.png"
    other = tmp_path / "x.uncompensated.csv"
    other.write_text("an older result\n")
    png.write_text("an older plot")
    code, _, err = run_cli(capsys, "run", "example-3.6", *FAST, "--set", "k=2.1", "--set",
                           "r=0.9", "--set", "N=10", "--stop-time", "1200", "--compare",
                           "--out", str(out), "--plot", str(png))
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "delaycomp: error: --compare, the uncompensated run: plant failed"), err
    assert f"kept in {other}.partial" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.csv",
                                                          "x.uncompensated.csv.partial"]
    assert read_csv(out)[1][-1][0] == 1200.0


@pytest.mark.parametrize("loop", ["lti", "model"])
def test_compare_takes_loop_files_whose_controller_has_a_mode(capsys, tmp_path, loop):
    """An LTI loop file (the shipped one of example-3.6) and a model loop file (the
    tutorial's cart) both write their other mode beside ``--out``."""
    if loop == "lti":
        path = tmp_path / "mine.toml"
        shutil.copy(scenarios.loop_file("example-3.6"), path)
        sets = ["--set", "r=0.3", "--stop-time", "4"]
    else:
        path = tmp_path / "cart.toml"
        for name in ("cart.toml", "cart.py"):
            shutil.copy(REPO / "docs" / "examples" / name, tmp_path / name)
        sets = ["--stop-time", "4"]
    out = tmp_path / "run.csv"
    code, _, err = run_cli(capsys, "run", str(path), *FAST, *sets, "--compare", "--out",
                           str(out))
    assert code == 0, err
    alone = tmp_path / "alone.csv"
    assert run_cli(capsys, "run", str(path), *FAST, *sets, "--set",
                   "controller.mode=uncompensated", "--out", str(alone))[0] == 0
    head, rows = read_csv(tmp_path / "run.uncompensated.csv")
    assert head == read_csv(out)[0] == read_csv(alone)[0]
    assert_columns_close(rows, read_csv(alone)[1], SAME_ARITHMETIC_ULPS, "uncompensated")


# -- 2. a scale on which both runs read ---------------------------------------------------

def _runs(r: float, stop: float = 20.0, u0: float | None = None):
    sc = scenarios.get("example-3.6")
    extra = [] if u0 is None else [f"u0={u0}"]
    return {m: run_loop(sc.make(sc.resolve([f"r={r}", f"mode={m}", *extra])), stop,
                        engine="inprocess") for m in ("compensated", "uncompensated")}


def _peak(result, name):
    return float(np.max(np.abs(result.column(name))))


def test_a_diverging_baseline_goes_to_a_symmetric_log_scale_said_on_the_figure():
    """Example 3.6, r = 0.3 > r_c: the uncompensated run grows, the compensated one
    converges. Every panel is on a symmetric log scale, linear within the compensated
    run's range (its largest |value| rounded up to 1, 2 or 5 times a power of ten, so
    within a factor 2.5 of it), and says so in its label and a note."""
    runs = _runs(0.3, u0=4.0)
    comp, bare = runs["compensated"], runs["uncompensated"]
    # the premise, from the runs themselves: one panel past the linear ratio
    assert max(_peak(bare, n) / _peak(comp, n) for n in comp.names) > LINEAR_RATIO
    fig = result_figure(comp, "t", compare=runs)
    try:
        for ax, name in zip(fig.axes, comp.names):
            assert ax.get_yscale() == "symlog"
            linthresh = ax.yaxis.get_transform().linthresh
            assert _peak(comp, name) <= linthresh < 2.5 * _peak(comp, name)
            notes = [t.get_text() for t in ax.texts]
            assert notes == [f"symmetric log scale: linear within \u00b1{linthresh:g}, "
                             "logarithmic beyond"]
            assert ax.get_ylabel().endswith("(symmetric log)")
            # both runs drawn in full (nothing clipped): the axis holds the largest value
            low, high = ax.get_ylim()
            assert low <= -0.99 * _peak(bare, name) or high >= 0.99 * _peak(bare, name)
    finally:
        _close(fig)


def test_a_converging_pair_stays_linear_with_no_note():
    """Example 3.6, r = 0.1 < r_c: both runs converge, their largest values are within
    the linear ratio, every panel linear, no note."""
    runs = _runs(0.1)
    comp, bare = runs["compensated"], runs["uncompensated"]
    for name in comp.names:
        ratio = _peak(bare, name) / _peak(comp, name)
        assert 1 / LINEAR_RATIO <= ratio <= LINEAR_RATIO
    fig = result_figure(comp, "t", compare=runs)
    try:
        assert [ax.get_yscale() for ax in fig.axes] == ["linear", "linear"]
        assert all(not ax.texts for ax in fig.axes)
        assert [ax.get_ylabel() for ax in fig.axes] == ["plant.x", "controller.u"]
    finally:
        _close(fig)


def test_one_run_is_linear_whatever_its_range():
    runs = _runs(0.5)
    fig = figure(runs["uncompensated"], "t")
    try:
        assert fig.axes[0].get_yscale() == "linear" and not fig.axes[0].texts
    finally:
        _close(fig)
    fig = figure(list(runs.values()), "t", list(runs), scale="linear")
    try:
        assert [ax.get_yscale() for ax in fig.axes] == ["linear", "linear"]
    finally:
        _close(fig)
    with pytest.raises(ValueError, match="scale 'log' is not allowed: auto or linear"):
        figure(list(runs.values()), "t", list(runs), scale="log")


@pytest.mark.parametrize("small,large,expected", [
    (1.0, LINEAR_RATIO, Scale()),                       # at the ratio: still linear
    (1.0, LINEAR_RATIO * (1 + 1e-9), Scale("symlog", 1.0)),
    (6.73, 35.2, Scale("symlog", 10.0)),
    (13.5, 1e4, Scale("symlog", 20.0)),
    (0.03, 4.0, Scale("symlog", 0.05)),
    (0.0, 5.0, Scale()),                                # a zero run: nothing to hold
])
def test_choose_scale_linear_part_holds_the_smaller_run(small, large, expected):
    got = choose_scale([[0.5 * small, -small], [large, 0.0]])
    assert got.kind == expected.kind
    if expected.linthresh is not None:
        assert got.linthresh is not None
        assert math.isclose(got.linthresh, expected.linthresh, rel_tol=1e-12)
        assert small <= got.linthresh < 2.5 * small


def test_a_figure_reads_one_way_throughout():
    """A panel whose runs are close goes to the symmetric log scale with the others
    (linear within its smaller run's range); a figure of close runs stays linear."""
    scales = panel_scales([[[1, -6.7], [1, -35.2]], [[-5, 13.5], [-2, -50]]])
    assert [s.kind for s in scales] == ["symlog", "symlog"]
    assert [s.linthresh for s in scales] == [10.0, 20.0]
    assert panel_scales([[[1, -1.1], [1, 0.6]]]) == [Scale()]


def test_run_help_says_where_the_other_run_goes_and_how_it_is_drawn(capsys):
    with pytest.raises(SystemExit):
        run_cli(capsys, "run", "--help")
    text = " ".join(capsys.readouterr().out.split())
    assert ("--out FILE.csv gets this run, as without --compare, and FILE.MODE.csv beside "
            "it the other (FILE.uncompensated.csv: the same columns and row times)") in text
    assert f"exceeds {LINEAR_RATIO:g} times the other's" in text
    assert "symmetric log scale (said on the plot)" in text


def test_compare_of_an_ssp_says_how_to_get_both(capsys, tmp_path):
    code, _, err = run_cli(capsys, "run", str(tmp_path / "loop.ssp"), "--compare", "--out",
                           str(tmp_path / "x.csv"))
    one_line_error(code, err, "--compare runs a scenario or a loop file (a FILE.ssp: run it "
                              "twice, with --set controller.mode=compensated and "
                              "=uncompensated)")
