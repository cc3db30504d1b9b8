"""A run replayed from its recipe (``delaycomp.orchestrator.replay``; from the command line
``delaycomp.cli.recipes``): a second ``run FILE.ssp`` of the same command sets the FMUs up
from ctypes as the first run did and steps them in the same core, without numpy or fmpy,
and writes the same rows bit for bit; anything that differs from the first run gives way
to the whole run."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.cli import main
from delaycomp.fmu.twins import native_fmus
from delaycomp.maths.channel import Channel
from delaycomp.orchestrator import native_core
from delaycomp.orchestrator.replay import NotReplayed, replay
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.tmpfiles import cache_root

from .test_oneface import DOUBLE_TOML

pytestmark = pytest.mark.skipif(native_core.core_status() is not None,
                                reason=f"{native_core.core_status()}")

REPLAYED = "replayed from the recipe of its first run"
GAVE_WAY = "the replay gave way"
KEPT = re.compile(r"its recipe kept for the next run of this command \((.+)\)")
#: the loop file of a user (a double integrator, ``tests/test_oneface.py``'s), both
#: delays lossy, jittered network channels (seeded)
NETWORK_LOOP = DOUBLE_TOML.replace("stop_time = 6.0", "stop_time = 3.0") + """
[meas_delay]
distribution = "uniform"
jitter = 0.35
loss_model = "bernoulli"
loss = 0.3
seed = 11

[input_delay]
distribution = "uniform"
jitter = 0.25
loss_model = "bernoulli"
loss = 0.3
seed = 5
"""


def same_bits(a, b) -> bool:
    """Equal to the bit (a -0.0 is not 0.0; the shapes agree)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.fixture(scope="module")
def archives(tmp_path_factory) -> dict[str, Path]:
    """Native archives, packed once: Example 3.6 (FMI 2.0 and 3.0), Example 2.4 (a model
    file's plant and controller, continuous input), a user's loop with network channels."""
    folder = tmp_path_factory.mktemp("replay")
    (folder / "dbl.toml").write_text(NETWORK_LOOP, encoding="utf-8")
    packed = {"ex36": ["example-3.6"], "ex36-fmi3": ["example-3.6", "--fmi", "3"],
              "ex24": ["example-2.4"], "network": [str(folder / "dbl.toml")]}
    out = {}
    for name, what in packed.items():
        out[name] = folder / f"{name}.ssp"
        assert main(["ssp", *what, "--native", "--out", str(out[name]), "-q"]) == 0
    return out


def run(capsys, *argv) -> tuple[int, str, str]:
    """``delaycomp run ARGV -v`` in this process: exit status, stdout, stderr."""
    capsys.readouterr()
    rc = main(["run", *map(str, argv), "-v"])
    out, err = capsys.readouterr()
    return rc, out, err


def rows_of(csv: Path) -> tuple[str, np.ndarray]:
    header, _, _ = csv.read_text().partition("\n")
    return header, np.loadtxt(csv, delimiter=",", skiprows=1, ndmin=2)


def untimed(text: str) -> str:
    """The summary line without its wall time."""
    return re.sub(r" in \d+\.\d+ s;", " in _ s;", text)


@pytest.mark.parametrize("which, options", [
    ("ex36", ["--stop-time", "7"]),
    ("ex36-fmi3", ["--stop-time", "7", "--output-interval", "0.5"]),
    ("ex24", ["--stop-time", "3", "--set", "plant.x0[2]=-0.25"]),
    ("network", ["--stepping", "native-core"]),
])
def test_the_second_run_is_replayed_and_writes_the_same_rows_bit_for_bit(
        archives, tmp_path, capsys, which, options):
    first, second = tmp_path / "first.csv", tmp_path / "second.csv"
    rc, out1, err1 = run(capsys, archives[which], *options, "--out", first)
    assert rc == 0, err1
    assert REPLAYED not in err1 and "stepped by the native core" in err1
    assert KEPT.search(err1)
    rc, out2, err2 = run(capsys, archives[which], *options, "--out", second)
    assert rc == 0, err2
    assert REPLAYED in err2 and GAVE_WAY not in err2
    h1, rows1 = rows_of(first)
    h2, rows2 = rows_of(second)
    assert h1 == h2 and len(rows1) > 10
    assert same_bits(rows1, rows2)
    assert untimed(out1) == untimed(out2)
    # -v says the same things, but for what each says of the recipe
    assert ([line for line in err2.splitlines() if REPLAYED not in line]
            == [line for line in err1.splitlines() if not KEPT.search(line)])


def test_without_out_the_replay_still_reports_the_run(archives, capsys):
    rc, out1, _ = run(capsys, archives["ex36"], "--stop-time", "3.5")
    rc2, out2, err2 = run(capsys, archives["ex36"], "--stop-time", "3.5")
    assert rc == rc2 == 0 and REPLAYED in err2
    assert untimed(out1) == untimed(out2) and "351 rows to t = 3.5" in out2


def recipe_file(archive: Path, options: list[str], tmp_path: Path, capsys) -> Path:
    """The recipe a first run of ``archive`` with ``options`` leaves (``-v`` says where)."""
    rc, _, err = run(capsys, archive, *options, "--out", tmp_path / "first.csv")
    assert rc == 0
    found = KEPT.search(err)
    assert found, err
    folder = Path(found[1])
    assert folder.parent == cache_root() / "recipes"
    return folder / "recipe.json"


@pytest.mark.parametrize("tamper, why, x0", [
    ("guid", "was not instantiated", 0.1),
    ("parameter", "messages logged", 0.2),
    ("binary", "binary is gone", 0.3),
    ("core", "is not at hand", 0.4),
    ("initial", "initial outputs differ", 0.5),
])
def test_a_replay_that_differs_gives_way_to_the_whole_run(archives, tmp_path, capsys,
                                                          tamper, why, x0):
    """A recipe that no longer holds (a wrong instantiation token, a parameter the FMU
    refuses, a binary gone, another core, an initial output that is not the recorded one):
    nothing of the replay is kept, the whole run writes the right rows, and leaves a
    recipe that holds again."""
    options = ["--stop-time", "2.5", "--set", f"plant.x0[1]={x0}"]
    path = recipe_file(archives["ex36"], options, tmp_path, capsys)
    stored = json.loads(path.read_text())
    recipe = stored["recipe"]
    if tamper == "guid":
        recipe["components"][0]["guid"] = "{00000000-0000-0000-0000-000000000000}"
    elif tamper == "parameter":  # the measurement delay's r: negative, refused
        delay = next(c for c in recipe["components"] if c["name"] == "meas_delay")
        delay["parameters"][0][2] = [-1.0]
    elif tamper == "binary":
        lib = path.parent / recipe["folders"][0] / recipe["components"][0]["library"]
        lib.unlink()
    elif tamper == "core":
        recipe["core"] = str(tmp_path / "no-core.so")
    else:
        _, comp, vrs, _ = recipe["ops"][0]
        recipe["initial"] = [[comp, vrs, [123.0] * len(vrs)]]
    path.write_text(json.dumps(stored))
    rc, _, err = run(capsys, archives["ex36"], *options, "--out", tmp_path / "again.csv")
    assert rc == 0, err
    assert GAVE_WAY in err and why in err, err
    assert "stepped by the native core" in err
    assert same_bits(rows_of(tmp_path / "first.csv")[1], rows_of(tmp_path / "again.csv")[1])
    assert not (tmp_path / "again.csv.part").exists()
    assert not (tmp_path / "again.csv.partial").exists()
    # the whole run kept a recipe that holds: the next run is replayed
    rc, _, err = run(capsys, archives["ex36"], *options, "--out", tmp_path / "third.csv")
    assert rc == 0 and REPLAYED in err and GAVE_WAY not in err


def test_a_recipe_that_cannot_be_read_is_no_recipe(archives, tmp_path, capsys):
    options = ["--stop-time", "1.5"]
    path = recipe_file(archives["ex36"], options, tmp_path, capsys)
    path.write_text("{not json")
    rc, _, err = run(capsys, archives["ex36"], *options, "--out", tmp_path / "b.csv")
    assert rc == 0 and REPLAYED not in err and GAVE_WAY not in err


def test_what_is_never_replayed_or_is_another_run(archives, tmp_path, capsys):
    """``--stepping python`` and ``--plot`` run whole; another stop time, ``--set`` or
    archive is another run (its own recipe); the output file's name is not."""
    ex36 = archives["ex36"]
    assert run(capsys, ex36, "--stop-time", "4.5", "--out", tmp_path / "a.csv")[0] == 0
    rc, _, err = run(capsys, ex36, "--stop-time", "4.5", "--stepping", "python")
    assert rc == 0 and REPLAYED not in err and "stepped by the Python master" in err
    rc, _, err = run(capsys, ex36, "--stop-time", "4.5", "--plot", tmp_path / "p.png")
    assert rc == 0 and REPLAYED not in err
    for other in (["--stop-time", "4.6"], ["--stop-time", "4.5", "--set", "plant.x0[1]=2"]):
        rc, _, err = run(capsys, ex36, *other)
        assert rc == 0 and REPLAYED not in err
    moved = tmp_path / "renamed.ssp"
    moved.write_bytes(ex36.read_bytes())
    rc, _, err = run(capsys, moved, "--stop-time", "4.5", "--out", tmp_path / "elsewhere.csv")
    assert rc == 0 and REPLAYED in err  # the same bytes, the same command


def test_a_python_fmu_leaves_no_recipe(tmp_path, capsys):
    archive = tmp_path / "py.ssp"
    assert main(["ssp", "example-3.6", "--python", "--out", str(archive), "-q"]) == 0
    for _ in range(2):
        rc, _, err = run(capsys, archive, "--stop-time", "0.5")
        assert rc == 0 and REPLAYED not in err and "stepped by the Python master" in err


def test_the_replay_imports_neither_numpy_nor_fmpy(archives, tmp_path):
    """What makes a short run short: the second process loads none of them."""
    probe = ("import sys; from delaycomp.cli import main; rc = main(sys.argv[1:]); "
             "print(rc, sorted({m.split('.')[0] for m in sys.modules} & "
             "{'numpy', 'fmpy', 'lxml', 'scipy'}))")
    argv = [sys.executable, "-c", probe, "run", str(archives["ex36"]), "--stop-time", "6.5",
            "--out", str(tmp_path / "o.csv"), "-q"]
    first = subprocess.run(argv, capture_output=True, text=True, check=True).stdout
    second = subprocess.run(argv, capture_output=True, text=True, check=True).stdout
    assert "'fmpy'" in first and "'numpy'" in first
    assert second.splitlines()[-1] == "0 []"


@pytest.mark.parametrize("scenario", ["example-3.6", "corollary-4.1", "network"])
def test_the_recipe_of_a_run_replays_it_bit_for_bit(scenario):
    """``recipe_of``/``replay`` without the command line: the rows ``replay`` hands on are
    the run's (a user's loop with network channels too: the channels' draws)."""
    if scenario == "network":
        loop = api.lti([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[-1.0, -1.6]], T=0.5,
                       r=0.2, tau=0.5, N=10, x0=[1.0, 0.0],
                       meas_channel=Channel(distribution="uniform", jitter=0.05,
                                            loss_model="bernoulli", loss=0.2, seed=11))
    else:
        loop = api.load(scenario)
    result = run_loop(loop, 3.0, fmus=native_fmus(loop), every=3)
    assert result.stepped_by == "native-core" and result.recipe is not None
    values: list[float] = []
    done = replay(result.recipe, lambda flat, n: values.extend(flat))
    width = len(result.names) + 1
    flat = np.column_stack([result.times, result.data])
    assert same_bits(np.array(values).reshape(-1, width), flat)
    assert done.rows == len(result.times) and done.names == result.names
    assert same_bits(done.last_row, result.data[-1])


def test_recipe_of_needs_a_run_that_said_nothing():
    """No recipe where the Python master stepped the run."""
    loop = api.load("example-3.6")
    result = run_loop(loop, 1.0, fmus=native_fmus(loop), stepping="python")
    assert result.recipe is None
    with pytest.raises(NotReplayed, match="format"):
        replay({"format": 0})
