"""The robustness map (issue 29 item 4: ``delaycomp.studies.robustness``, ``api.robustness``,
``delaycomp robustness``) against the per-point in-process runs with the same seeds.

With ``runs = 3`` the reported quantiles are order statistics of the three runs (the
inverted distribution function: p50 the second smallest, p90 and p99 the largest) and
``stable`` their count, so every number of a row is checked against three
``api.run(engine="inprocess")`` runs built from the loop file with the channel's
``jitter``, ``loss`` and ``seed`` written into its table.

Tolerances: Example 3.6 (``n = m = 1``) steps the same doubles in the same order on both
engines (``tests/test_batch_channel.py``: bit for bit), so its final norms are equal and
its costs differ only by the order of the cost's sum (2000 positive terms: at most
2000 eps ~ 4.4e-13 relative; held to 1e-12). For the ``n = 3`` loop the per-point engine's
matrix products may sum in another order: ``REL = 1e-12`` of the run's scale, as there.
"""

from __future__ import annotations

import copy
import csv
import math
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.cli import main
from delaycomp.maths.channel import ChannelLine
from delaycomp.paper.scenarios import loop_file
from delaycomp.studies import robustness as rb
from delaycomp.studies.sweep import result_metrics
from delaycomp.system.loopfile import LoopData, LoopFile, build, channel_of

REL = 1e-12
MYLOOP = Path(__file__).resolve().parents[1] / "docs" / "examples" / "myloop.toml"


def _reference(path: Path, on: str, jitter: float, loss: float, mode: str, seed: int,
               runs: int, stop: float, extra: dict | None = None) -> list[dict]:
    """The three per-point runs of one row: stable, final norm, cost each."""
    src = LoopFile(path)
    out = []
    other = "input_delay" if on == "meas_delay" else "meas_delay"
    for i in range(runs):
        data = copy.deepcopy(src.resolve([]))
        data.update(copy.deepcopy(extra or {}))
        data[on] = {**data.get(on, {}), "distribution": "uniform", "jitter": jitter,
                    "loss_model": "bernoulli", "loss": loss, "seed": seed + i}
        if other in data:
            data[other] = {**data[other], "seed": seed + runs + i}
        data["controller"] = {**data["controller"], **rb.MODE_KEYS[mode][0]}
        loop = build(data, src.base, name="ref")
        res = api.run(loop, engine="inprocess", stop_time=stop)
        m = result_metrics(loop, res)
        n = loop.lti.A.shape[0]
        h = loop.timing.T / loop.timing.N
        ticks = round(stop / h)
        m_in = loop.lti.B.shape[1]
        x, u = res.data[:ticks, :n], res.data[:ticks, n:n + m_in]
        # the plant's input: the controller's output through the input channel (replayed
        # with the channel's own line), else through the constant input delay
        tau = loop.lti.tau if loop.lti.tau_true is None else loop.lti.tau_true
        if "input_delay" in data:
            line = ChannelLine(channel_of(data["input_delay"], "input_delay", src.base, tau),
                               u.shape[1], h, list(loop.lti.u0))
            v = np.array([line.step(list(uk))[0] for uk in u])
        else:
            D = round(tau / h)
            v = np.vstack([np.tile(loop.lti.u0, (min(D, ticks), 1)), u[:max(0, ticks - D)]])
        cost = float(h * np.sum(x * x) + h * np.sum(v * v))
        out.append({"stable": m["stable"], "final": m["final_norm"], "cost": cost,
                    "rho": m["rho"]})
    return out


def _check_row(row: dict, refs: list[dict], rel: float) -> None:
    # no run so close to rho = 1 that the engines' fits could round to both sides
    assert all(abs(r["rho"] - 1) > 1e-6 for r in refs)
    assert row["stable"] == sum(r["stable"] for r in refs)
    assert row["runs"] == len(refs) == 3
    for name, key in (("cost", "cost"), ("final", "final")):
        ordered = sorted(r[key] for r in refs)
        for q, want in ((50, ordered[1]), (90, ordered[2]), (99, ordered[2])):
            assert row[f"{name}_p{q}"] == pytest.approx(want, rel=rel, abs=0), (name, q)
    assert (row["p_low"], row["p_high"]) == rb.wilson(row["stable"], 3)


def test_example_3_6_rows_are_the_per_point_runs():
    path = loop_file("example-3.6")
    m = rb.robustness(LoopFile(path), [0.0, 0.3], [0.0, 0.25], 3, seed=17,
                      stop_time=20.0)
    assert [(r["jitter"], r["loss"], r["mode"]) for r in m.rows] == [
        (j, v, md) for j in (0.0, 0.3) for v in (0.0, 0.25)
        for md in ("compensated", "uncompensated")]
    for row in m.rows:
        if row["jitter"] == 0.0 and row["loss"] == 0.0 and row["mode"] == "uncompensated":
            continue  # a constant delay: covered by the others (and tests/test_batch.py)
        refs = _reference(path, "meas_delay", row["jitter"], row["loss"], row["mode"], 17, 3,
                          20.0)
        _check_row(row, refs, 1e-12)


def test_the_n3_loop_through_the_input_channel_is_the_per_point_runs():
    # myloop.toml (n = 3, m = 2) with a lossy measurement channel of its own (the other
    # role's table: its seeds follow the swept one's) and the grid on the input
    extra = {"meas_delay": {"distribution": "uniform", "jitter": 0.1, "loss": 0.1,
                            "loss_model": "bernoulli"}}
    src = LoopFile(MYLOOP)
    data = {**src.resolve([]), **extra}
    m = rb.robustness(LoopData(data, MYLOOP.parent, name="myloop"), [0.3], [0.2], 3,
                      seed=5, on="input_delay", modes=("compensated",), stop_time=6.0)
    refs = _reference(MYLOOP, "input_delay", 0.3, 0.2, "compensated", 5, 3, 6.0, extra)
    _check_row(m.rows[0], refs, REL)


@pytest.mark.skipif(not rb.stamped_available(),
                    reason="run_lti_channels does not read time stamps yet (stamps=True)")
def test_the_stamped_mode_is_the_per_point_time_stamp_controller():
    # the hook for the time-stamp controller: [controller] stamps = true in process
    m = rb.robustness(LoopFile(MYLOOP), [0.4], [0.3], 3, seed=2, modes=("stamped",),
                      stop_time=6.0)
    refs = _reference(MYLOOP, "meas_delay", 0.4, 0.3, "stamped", 2, 3, 6.0)
    _check_row(m.rows[0], refs, REL)


def test_the_map_does_not_depend_on_the_chunking_and_the_seed_moves_it():
    src = LoopFile(loop_file("example-3.6"))
    args = ([0.1, 0.2], [0.1], 7)
    a = rb.robustness(src, *args, seed=3, stop_time=10.0)
    b = rb.robustness(src, *args, seed=3, stop_time=10.0, chunk=4)
    assert a.rows == b.rows
    c = rb.robustness(src, *args, seed=4, stop_time=10.0)
    assert [r["cost_p50"] for r in a.rows] != [r["cost_p50"] for r in c.rows]
    # the modes share their draws: a one-mode map is the other's rows
    d = rb.robustness(src, *args, seed=3, stop_time=10.0, modes=("uncompensated",))
    assert d.rows == [r for r in a.rows if r["mode"] == "uncompensated"]


def test_wilson_interval():
    # the score interval solves |p - pi| = z sqrt(pi (1 - pi) / n) for pi: check that
    for k, n in ((0, 10), (3, 10), (50, 100), (999, 1000), (1000, 1000)):
        lo, hi = rb.wilson(k, n)
        p = k / n
        for pi, end in ((lo, 0.0), (hi, 1.0)):
            if pi == end:  # the interval reaches the end: k = 0 or k = n only
                assert k in (0, n)
                continue
            assert abs(p - pi) == pytest.approx(rb.Z95 * math.sqrt(pi * (1 - pi) / n),
                                                rel=1e-9)
        assert lo <= p <= hi


def test_refusals_are_one_line():
    src = LoopFile(loop_file("example-3.6"))
    with pytest.raises(api.ParameterError, match=r"^runs = 0 is not allowed"):
        rb.robustness(src, [0.0], [0.0], 0)
    with pytest.raises(api.ParameterError, match=r"^loss = \[1.5\] is not allowed"):
        rb.robustness(src, [0.0], [1.5], 3)
    with pytest.raises(api.ParameterError, match=r"^on = 'plant'"):
        rb.robustness(src, [0.0], [0.0], 3, on="plant")
    with pytest.raises(api.ParameterError, match="max_delay is required"):
        rb.robustness(src, [0.1], [0.0], 3, distribution="exponential")
    if not rb.stamped_available():
        with pytest.raises(api.ParameterError, match="modes = 'stamped' is not allowed"):
            rb.robustness(src, [0.0], [0.0], 3, modes=("stamped",))


def test_command_writes_the_csv_and_the_maps(tmp_path, capsys):
    out, png = tmp_path / "map.csv", tmp_path / "map.png"
    rc = main(["robustness", str(loop_file("example-3.6")), "--jitter", "0:0.2:2",
               "--loss", "0:0.3:2", "--runs", "4", "--seed", "9", "--stop-time", "10",
               "--out", str(out), "--plot", str(png)])
    assert rc == 0
    rows = list(csv.DictReader(out.read_text().splitlines()))
    assert tuple(rows[0]) == rb.COLUMNS
    assert len(rows) == 2 * 2 * 2
    assert png.stat().st_size > 0
    api_rows = api.robustness(loop_file("example-3.6"), [0.0, 0.2], [0.0, 0.3], 4, seed=9,
                              stop_time=10.0).rows
    assert [float(r["cost_p50"]) for r in rows] == [r["cost_p50"] for r in api_rows]
    assert "wrote" in capsys.readouterr().out
    for bad, says in ((["--runs", "0"], "runs = 0"), (["--jitter", "0:1"], "--jitter"),
                      (["--on", "x"], "on = 'x'"), (["--modes", "a"], "modes = 'a'")):
        argv = ["robustness", str(loop_file("example-3.6")), "--jitter", "0:0.2:2",
                "--loss", "0:0.3:2", "--runs", "2", "--out", str(tmp_path / "x.csv"), *bad]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1


def test_ctrl_c_writes_nothing_and_exits_130(tmp_path, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(rb, "robustness", interrupted)
    out = tmp_path / "map.csv"
    rc = main(["robustness", str(loop_file("example-3.6")), "--jitter", "0:0.2:2",
               "--loss", "0:0.3:2", "--runs", "2", "--out", str(out)])
    assert rc == 130
    assert capsys.readouterr().err.strip() == "delaycomp: interrupted"
    assert list(tmp_path.iterdir()) == []
