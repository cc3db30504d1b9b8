"""A sweep's memory is bounded before it is spent (issue 30, item 3): the grid streams in
pieces and stream chunks, whatever its size; what cannot fit is refused up front, in one
line, with the estimate; streamed results are the unstreamed ones."""

from __future__ import annotations

import resource
import subprocess
import sys

import numpy as np
import pytest

from delaycomp import api
from delaycomp.errors import ParameterError
from delaycomp.formats import outputs
from delaycomp.studies import sweep, sweep_batch, sweep_size
from delaycomp.studies.axes import Axis, parse_grid
from delaycomp.studies.sweep import SweepOptions

from .conftest import REPO

#: The command in a child process with the stream's sizes given first (STREAM PIECE), the
#: peak of its address space (VmPeak, kB) written to the file named last.
CHILD = """
import atexit, sys
from delaycomp.studies import sweep_size
sweep_size.STREAM_POINTS, sweep_size.PIECE_POINTS = int(sys.argv[1]), int(sys.argv[2])
peak_file = sys.argv[-1]

def peak():
    with open("/proc/self/status") as fh:
        kb = next(line.split()[1] for line in fh if line.startswith("VmPeak:"))
    with open(peak_file, "w") as out:
        out.write(kb)

atexit.register(peak)
sys.argv = ["delaycomp", *sys.argv[3:-1]]
from delaycomp.cli import entry
entry()
"""


def child(args: list[str], stream: int, piece: int, peak_file, limit: int | None = None):
    """``delaycomp ARGS`` in a child process whose stream chunks hold ``stream`` points,
    under an address-space limit of ``limit`` bytes."""
    def limited():
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return subprocess.run([sys.executable, "-c", CHILD, str(stream), str(piece), *args,
                           str(peak_file)], capture_output=True, text=True, cwd=REPO,
                          timeout=300, preexec_fn=limited)


def sweep_args(out, k_count: int) -> list[str]:
    return ["sweep", "example-3.6", "--grid", f"k=0.5:3:{k_count}", "--grid", "r=0:0.98:1000",
            "--stop-time", "3", "--workers", "1", "--out", str(out)]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")
# the child is forked to set its limit, then execs: JAX, imported in this process by other
# tests, warns at any fork about its threads, which the exec'd child never uses
@pytest.mark.filterwarnings("ignore:os.fork\\(\\) was called:RuntimeWarning")
# a soak (15 s): the fast tier streams in test_streamed_results_are_the_unstreamed_ones
@pytest.mark.slow
def test_a_grid_streams_in_memory_its_points_would_exceed(tmp_path):
    """300 000 points under an address-space limit of a small sweep's peak plus 160 MB.
    Held together (before: each point's grid texts, loop-file values, design, metrics
    and row, about 1.1 kB a point) they need about 330 MB more than the small sweep
    (measured: the run failed with MemoryError); streamed in chunks of 16384 points
    they need about 70 MB more (measured), most of it the validated designs kept for
    the run (137 bytes a point): the limit lies between, with room on both sides."""
    small = tmp_path / "small.csv"
    proc = child(sweep_args(small, 1), 16384, 4096, tmp_path / "small.kb")
    assert proc.returncode == 0, proc.stderr
    base = int((tmp_path / "small.kb").read_text()) * 1024
    out = tmp_path / "map.csv"
    proc = child(sweep_args(out, 300), 16384, 4096, tmp_path / "map.kb",
                 limit=base + 200 * 2**20)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "300000 points" in proc.stdout
    with open(out, newline="") as fh:
        assert sum(1 for _ in fh) == 1 + 300_000
    assert not (tmp_path / "map.csv.part").exists()


def test_a_request_that_cannot_fit_is_refused_up_front(monkeypatch, tmp_path):
    """On a machine of 8 GB: the rows of 2 x 10^7 points returned together (360 bytes
    each) need more than half of it, refused before any point is resolved (which would
    take minutes); streamed, the same grid fits (its working set does not grow with
    it)."""
    monkeypatch.setattr(outputs, "physical_memory", lambda: 8 * 10**9)
    grid = {"k": [0.5 + i * 1e-4 for i in range(20_000)], "r": [0.0] * 1000}
    with pytest.raises(ParameterError) as exc:
        api.sweep("example-3.6", grid, stop_time=5.0)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("--grid: 2e+07 points need about")
    assert "GB of memory" in msg and "api.iter_sweep" in msg
    axes = [parse_grid("k=0.5:3:20000"), parse_grid("r=0:0.98:1000")]
    count, _ = sweep.check_sweep_size("example-3.6", axes, [],
                                      SweepOptions(stop=5.0, engine="batch"), held=False)
    assert count == 20_000_000
    total, rows = sweep.sweep_memory(count, 2, held=False, kept=sweep.BYTES_PER_KEPT_LTI)
    assert rows == 0 and total < 2 * 10**9


def test_the_command_refuses_in_one_line_before_anything_runs(tmp_path):
    """A plot of more points than the map has pixels, and a sweep on a machine whose
    memory cannot hold even its stream (a limit of 100 MB given to the estimate): exit 2,
    one line, nothing written."""
    out, png = tmp_path / "map.csv", tmp_path / "map.png"
    proc = subprocess.run([sys.executable, "-m", "delaycomp", *sweep_args(out, 2000),
                           "--plot", str(png)], capture_output=True, text=True, cwd=REPO,
                          timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "--plot: 2e+06 points" in proc.stderr
    code = ("import sys; from delaycomp.formats import outputs; "
            "outputs.physical_memory = lambda: 10**8; "
            "sys.argv = ['delaycomp', *sys.argv[1:]]; "
            "from delaycomp.cli import entry; entry()")
    proc = subprocess.run([sys.executable, "-c", code, *sweep_args(out, 300)],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "need about" in proc.stderr
    assert "over half of this machine's 100 MB" in proc.stderr
    assert not out.exists() and not png.exists()


GRIDS = [  # (source, grids, sets, stop, engine, exact, chunk)
    ("example-3.6", ["k=0.5:3:7", "r=0:0.9:10"], ["mode=uncompensated"], 6.0, "batch", False,
     4),
    ("example-3.6", ["k=1e200:1e300:2", "r=0:0.2:3"], [], 5.0, "batch", False, 2),  # diverge
    ("corollary-3.7", ["n=1:3:3", "r=0:0.3:4"], [], 4.0, "batch", False, 4),  # 3 groups
    ("example-2.4", ["r=0:0.5:6", "tau=0:0.5:3"], [], 2.0, "batch", False, 2),  # a model
    ("example-3.8", ["r=0.1:0.3:3"], ["predictor=numerical"], 2.0, "batch", False, 2),
    ("example-3.6", ["k=0.5:3:4", "r=0:0.9:4"], [], None, "fmu", True, None),  # --exact
    ("example-3.6", ["k=1:2:2", "r=0:0.5:3"], [], 3.0, "inprocess", False, None),
]


@pytest.mark.parametrize("source,grids,sets,stop,engine,exact,chunk", GRIDS)
def test_streamed_results_are_the_unstreamed_ones(monkeypatch, source, grids, sets, stop,
                                                  engine, exact, chunk):
    """Stream chunks of 4 points (pieces of 2; none of the validated points kept, so that
    every piece is resolved again) against the whole grid in one: the same rows, bit for
    bit, and the same notes. The batch engine's chunks (``chunk`` points; a stream chunk
    holds a whole number of them) are alike on both sides: its arithmetic per point
    depends on a chunk's size in the last bits (tests/test_batch.py), not on the stream.
    The groups of Corollary 3.7 (one per chain length ``n``) are a stream chunk each."""
    axes = [parse_grid(g) for g in grids]
    options = SweepOptions(stop=stop, engine=engine, exact=exact, chunk=chunk, verbosity=0)
    whole_notes: list[str] = []
    whole = sweep.run_sweep(source, axes, sets, options, notes=whole_notes)
    monkeypatch.setattr(sweep_size, "STREAM_POINTS", 4)
    monkeypatch.setattr(sweep_size, "PIECE_POINTS", 2)
    monkeypatch.setattr(sweep_size, "KEEP_BYTES", 0)
    notes: list[str] = []
    rows = sweep.iter_sweep(source, axes, sets, options, notes=notes)
    assert notes == []  # the notes come with the last row
    rows = list(rows)
    assert [repr(list(r.items())) for r in rows] == [repr(list(r.items())) for r in whole]
    assert notes == whole_notes


def test_every_piece_is_validated_before_any_point_runs(monkeypatch):
    """Pieces of 2 points: the one bad point (off the base grid) is the last; it is refused
    before anything runs, on the batch engine and on the per-point one."""
    ran = []
    monkeypatch.setattr(sweep_batch, "run_chunks", lambda *a, **k: ran.append(a) or [])
    monkeypatch.setattr(sweep, "_run_jobs", lambda *a, **k: ran.append(a) or [])
    monkeypatch.setattr(sweep_size, "STREAM_POINTS", 2)
    monkeypatch.setattr(sweep_size, "PIECE_POINTS", 2)
    axes = [Axis("r", (0.0, 0.01, 0.02, 0.03, 0.035))]
    for engine in ("batch", "inprocess"):
        with pytest.raises(ParameterError, match=r"^grid point r=0\.035: .*multiple of"):
            sweep.iter_sweep("example-3.6", axes, [], SweepOptions(stop=2.0, engine=engine))
        with pytest.raises(ParameterError, match=r"^grid point r=0\.035: .*multiple of"):
            sweep.run_sweep("example-3.6", axes, [], SweepOptions(stop=2.0, engine=engine))
    assert ran == []


def test_a_sweep_that_stops_midway_leaves_no_result(monkeypatch, tmp_path):
    """A failure in the second stream chunk, after the first one's rows were written: the
    ``.part`` file is removed and no CSV appears (exit 1, one line)."""
    from delaycomp import cli

    calls = []
    run_batch = sweep._run_batch

    def failing(*args):
        calls.append(1)
        if len(calls) == 2:
            assert (tmp_path / "map.csv.part").exists()  # the first chunk's rows, buffered
            raise RuntimeError("out of luck")
        return run_batch(*args)

    monkeypatch.setattr(sweep, "_run_batch", failing)
    monkeypatch.setattr(sweep_size, "STREAM_POINTS", 4)
    monkeypatch.setattr(sweep_size, "PIECE_POINTS", 4)
    out = tmp_path / "map.csv"
    rc = cli.main(["sweep", "example-3.6", "--grid", "r=0:0.5:6", "--stop-time", "3",
                   "--workers", "1", "--out", str(out)])
    assert rc == 1 and len(calls) == 2
    assert list(tmp_path.iterdir()) == []


def test_the_plot_takes_the_streamed_rho(tmp_path):
    """``--plot`` draws from the array of ``rho`` a stream keeps (8 bytes a point), the
    same picture as from the rows."""
    rows = [{"rho": 0.5, "stable": 1, "failed": ""}, {"rho": None, "stable": None,
                                                      "failed": "plant failed"},
            {"rho": 1.5, "stable": 0, "failed": ""}]
    tally = sweep.Tally(rho=np.empty(3))
    assert list(tally.count(rows)) == rows
    assert (tally.points, tally.stable, tally.failed) == (3, 1, 1)
    axes = [parse_grid("r=0:1:3")]
    sweep.plot_sweep(rows, axes, tmp_path / "a.png", "t")
    sweep.plot_sweep(tally.rho, axes, tmp_path / "b.png", "t")
    import matplotlib.image

    # the same picture: the decoded pixels equal (not the files' bytes)
    assert np.array_equal(matplotlib.image.imread(tmp_path / "a.png"),
                          matplotlib.image.imread(tmp_path / "b.png"))
