"""A network channel in a loop file and in ``run`` (issue 29, item 3, slice a).

``[meas_delay]`` and ``[input_delay]`` put ``delaycomp.maths.channel.Channel`` in the
place of the loop's constant delays. What is held here: the tables build the channel FMU
with the table's parameters (and nothing else changes); bad values are one line naming
``table.key``; on every engine of ``run`` a constant channel without loss gives the delay's
CSV bit for bit, a jittered and lossy one gives the same numbers through the FMI layer as
in process and is fixed by its seed; the controller's measurement is what ``ChannelLine``
alone makes of the plant's recorded output, and one packet's delay is checked against the
draw written out again here (SplitMix64); commands that do not handle a channel yet refuse
it in one line.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from delaycomp import api
from delaycomp.cli import main
from delaycomp.errors import ParameterError
from delaycomp.maths.channel import Channel, ChannelLine
from delaycomp.system import Port
from delaycomp.system.loopfile import LoopData, build, read_trace

from .external import need

#: the double integrator of ``delaycomp.api``'s example: n = 2 measured states, m = 1
#: input, r = 0.36 (18 base steps), tau = 0.4 (two periods)
BASE = {"name": "dbl", "T": 0.2, "N": 20, "r": 0.36, "tau": 0.4, "stop_time": 6.0,
        "plant": {"A": [[0.0, 1.0], [0.0, 0.0]], "B": [[0.0], [1.0]], "x0": [1.0, 0.0]},
        "controller": {"K": [[-1.0, -1.6]]}}
#: jitter above T (0.2 s) and 30 % loss on both delays
LOSSY = {"meas_delay": {"distribution": "uniform", "jitter": 0.35, "loss_model": "bernoulli",
                        "loss": 0.3, "seed": 11},
         "input_delay": {"distribution": "uniform", "jitter": 0.25,
                         "loss_model": "bernoulli", "loss": 0.3, "seed": 5}}


def _data(**tables) -> dict:
    data = copy.deepcopy(BASE)
    data.update(copy.deepcopy(tables))
    return data


def _loop(tmp_path: Path | None = None, **tables):
    return build(_data(**tables), tmp_path or Path.cwd(), name="dbl")


def _toml(path: Path, **tables) -> Path:
    """The loop as a file (the CLI's way in)."""
    def value(v):
        if isinstance(v, str):
            return f'"{v}"'
        return repr(v)
    lines = [f"{k} = {value(v)}" for k, v in BASE.items() if not isinstance(v, dict)]
    for table, body in [*((k, v) for k, v in BASE.items() if isinstance(v, dict)),
                        *tables.items()]:
        lines.append(f"[{table}]")
        lines += [f"{k} = {value(v)}" for k, v in body.items()]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _same(a, b) -> None:
    """Bit for bit: the same columns, times and every value the same double."""
    assert a.names == b.names
    assert np.array_equal(a.times, b.times) and np.array_equal(a.data, b.data)


# -- the tables ----------------------------------------------------------------------------

def test_the_tables_put_the_channel_fmu_in_the_delays_places():
    plain = _loop()
    loop = _loop(**LOSSY)
    meas, inp = loop.by_role("meas_delay"), loop.by_role("input_delay")
    assert meas.source.kind == "channel" and meas.source.config == {"n": 2}
    assert inp.source.kind == "channel" and inp.source.config == {"n": 1}
    # the least delay defaults to the loop's true delay; the history stays the delay's
    assert meas.parameters["delay"] == 0.36 and inp.parameters["delay"] == 0.4
    assert meas.parameters["u0[1]"] == 1.0 and meas.parameters["u0[2]"] == 0.0
    assert meas.parameters["jitter"] == 0.35 and meas.parameters["seed"] == 11
    assert meas.parameters["loss_model"] == "bernoulli" and meas.parameters["loss"] == 0.3
    # nothing else changes: the other instances, the wiring, the timing, the design
    assert [i for i in loop.instances if i.role in ("plant", "controller")] == \
        [i for i in plain.instances if i.role in ("plant", "controller")]
    assert loop.connections == plain.connections and loop.timing == plain.timing
    assert loop.lti is not None and np.array_equal(loop.lti.K, plain.lti.K)


def test_without_the_tables_the_loop_is_as_before(tmp_path):
    loop = _loop()
    assert {i.source.kind for i in loop.instances} == {"plant", "delay", "controller"}
    # r_true feeds the channel's least delay as it feeds the delay
    true = build({**_data(meas_delay={}), "r_true": 0.5}, tmp_path)
    assert true.by_role("meas_delay").parameters["delay"] == 0.5


@pytest.mark.parametrize("table,key,value,allowed", [
    ("meas_delay", "loss", 2.0, "<= 1.0"),
    ("meas_delay", "jitter", -0.1, ">= 0.0"),
    ("input_delay", "distribution", "pareto", "constant, uniform, exponential, gamma, trace"),
    ("input_delay", "policy", "newest", "in_order, drop_stale"),
    ("meas_delay", "seed", -1, "0 .. 2147483647"),
    ("meas_delay", "seed", 1.5, "an integer"),
    ("meas_delay", "shape", 0.0, "> 0"),
    ("meas_delay", "max_delay", 0.1, ">= 0.36"),   # below the least delay
    ("meas_delay", "jitter", "x", "a number"),
])
def test_a_bad_value_is_one_line_naming_table_and_key(table, key, value, allowed):
    with pytest.raises(ParameterError) as info:
        _loop(**{table: {key: value}})
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{table}.{key} = "), message
    assert allowed in message, message


def test_exponential_without_a_timeout_is_refused_naming_max_delay():
    with pytest.raises(ParameterError, match=r"^meas_delay\.max_delay is required"):
        _loop(meas_delay={"distribution": "exponential", "jitter": 0.1})


def test_an_unknown_key_is_refused_with_the_allowed_ones():
    with pytest.raises(ParameterError) as info:
        _loop(meas_delay={"jiter": 0.1})
    message = str(info.value)
    assert "[meas_delay]: unknown key 'jiter'" in message
    for key in ("distribution", "jitter", "trace", "loss_model", "seed", "period"):
        assert key in message


def test_bad_values_exit_2_in_one_line_from_the_cli(tmp_path, capsys):
    path = _toml(tmp_path / "bad.toml", meas_delay={"loss_model": "bernoulli", "loss": 1.5})
    assert main(["run", str(path), "--engine", "inprocess"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert "meas_delay.loss = 1.5 is not allowed" in err


def test_a_trace_file(tmp_path):
    (tmp_path / "t.csv").write_text("time,delay\n0,0.4\n1,\n2,nan\n3,0.5\n",
                                    encoding="utf-8")
    (tmp_path / "bare.csv").write_text("0.4\n0.45\n", encoding="utf-8")
    got = read_trace(tmp_path / "t.csv", "meas_delay.trace")
    assert got[0] == 0.4 and math.isnan(got[1]) and math.isnan(got[2]) and got[3] == 0.5
    assert read_trace(tmp_path / "bare.csv", "x") == (0.4, 0.45)
    loop = build(_data(meas_delay={"distribution": "trace", "trace": "t.csv"}), tmp_path)
    meas = loop.by_role("meas_delay")
    assert meas.source.config == {"n": 2, "L": 4}
    # a lost packet travels as a negative entry; the least delay is the trace's smallest
    assert [meas.parameters[f"trace[{i}]"] for i in range(1, 5)] == [0.4, -1.0, -1.0, 0.5]
    assert meas.parameters["delay"] == 0.4
    (tmp_path / "neg.csv").write_text("delay\n0.4\n-0.1\n", encoding="utf-8")
    with pytest.raises(ParameterError, match=r"^meas_delay\.trace = 'neg.csv': delay 2 "):
        build(_data(meas_delay={"distribution": "trace", "trace": "neg.csv"}), tmp_path)
    with pytest.raises(Exception, match="no such file"):
        build(_data(meas_delay={"distribution": "trace", "trace": "none.csv"}), tmp_path)


def test_the_trace_limit_is_the_channel_fmus():
    from delaycomp.fmu.build import TRACE_MAX as FMU_MAX
    from delaycomp.system.loopfile import TRACE_MAX

    assert TRACE_MAX == FMU_MAX


def test_set_reaches_the_tables(tmp_path):
    path = _toml(tmp_path / "l.toml", meas_delay={"distribution": "uniform", "jitter": 0.1})
    loop = api.load(path, ["meas_delay.seed=3", "input_delay.jitter=0.05",
                           "input_delay.distribution=uniform"])
    assert loop.by_role("meas_delay").parameters["seed"] == 3
    assert loop.by_role("input_delay").source.kind == "channel"


# -- run on every engine -------------------------------------------------------------------

CONSTANT = {"meas_delay": {"distribution": "constant"},
            "input_delay": {"distribution": "constant", "loss_model": "none"}}


@pytest.mark.parametrize("engine,fmus", [("inprocess", "auto"), ("fmu", "python")])
def test_a_constant_channel_is_the_delay_bit_for_bit(fmu_dir, engine, fmus):
    plain = api.run(_loop(), engine=engine, fmus=fmus, fmu_dir=fmu_dir)
    channel = api.run(_loop(**CONSTANT), engine=engine, fmus=fmus, fmu_dir=fmu_dir)
    assert plain.row_count == channel.row_count == 601  # 6 s at h = 0.01
    _same(plain, channel)


def test_native_runs_where_the_channel_has_a_native_twin(fmu_dir, tmp_path):
    """With the channel's native twin registered (``FMUS["channel"].native``), the native
    run of a constant channel is the native delay's bit for bit; without it, ``auto`` runs
    the loop's Python FMUs and says why, ``native`` refuses."""
    from delaycomp.fmu.build import FMUS

    loop = _loop(**CONSTANT)
    if not FMUS["channel"].native:
        files, why = api.choose_fmus(loop, "auto", fmu_dir)
        assert files is None and "channel" in why
        with pytest.raises(ValueError, match="channel"):
            api.choose_fmus(loop, "native", fmu_dir)
        return
    from delaycomp.fmu.native import NativeBuildError, compiler

    need("cc", compiler, (NativeBuildError,), "the native loop over a channel")
    plain = api.run(_loop(), fmus="native", fmu_dir=tmp_path)
    _same(plain, api.run(loop, fmus="native", fmu_dir=tmp_path))


def test_cli_run_of_a_constant_channel_writes_the_same_csv(tmp_path):
    for name, tables in (("plain", {}), ("channel", CONSTANT)):
        path = _toml(tmp_path / f"{name}.toml", **tables)
        assert main(["run", str(path), "--engine", "inprocess", "--out",
                     str(tmp_path / f"{name}.csv")]) == 0
    plain, channel = (tmp_path / "plain.csv", tmp_path / "channel.csv")
    assert plain.read_text().splitlines()[0] == channel.read_text().splitlines()[0]
    assert np.array_equal(np.loadtxt(plain, delimiter=",", skiprows=1),
                          np.loadtxt(channel, delimiter=",", skiprows=1))


def test_a_lossy_channel_fmu_and_in_process_agree_and_the_seed_fixes_it(fmu_dir):
    loop = _loop(**LOSSY)
    inproc = api.run(loop, engine="inprocess")
    fmu = api.run(loop, fmus="python", fmu_dir=fmu_dir)
    # the same slave code behind the FMI layer (fmpy passes the doubles as they are):
    # round-off at most, in practice nothing
    for name in inproc.names:
        np.testing.assert_allclose(fmu[name], inproc[name], rtol=0, atol=1e-12)
    _same(inproc, api.run(_loop(**LOSSY), engine="inprocess"))  # the same seed
    other = copy.deepcopy(LOSSY)
    other["meas_delay"]["seed"] = 12
    changed = api.run(_loop(**other), engine="inprocess")
    assert not np.array_equal(changed["plant.x1"], inproc["plant.x1"])
    # and the channel acts: the run is not the constant delay's
    assert not np.array_equal(api.run(_loop(), engine="inprocess")["plant.x1"],
                              inproc["plant.x1"])


@pytest.mark.parametrize("engine,fmus", [("inprocess", "auto"), ("fmu", "python")])
def test_a_playout_buffer_turns_a_varying_input_delay_into_a_constant_one(fmu_dir, engine,
                                                                        fmus):
    """Issue 29, item 2: the input delay jitters between 0.4 and 0.6 s (packets overtake
    each other); a play-out buffer on the actuator side (``policy = "playout"``) applies
    each command at its send time + 0.6 s, the largest delay. The loop is then the loop
    with the constant input delay 0.6 (= 3 T, which the controller compensates exactly),
    bit for bit; the same channel delivering in order is not."""
    jittered = {"distribution": "uniform", "delay": 0.4, "jitter": 0.2, "seed": 5}
    data = {**BASE, "tau": 0.6}

    def run(**tables):
        d = copy.deepcopy(data)
        d.update(copy.deepcopy(tables))
        return api.run(build(d, Path.cwd(), name="dbl"), engine=engine, fmus=fmus,
                       fmu_dir=fmu_dir)

    constant = run()
    _same(constant, run(input_delay={**jittered, "policy": "playout"}))
    in_order = run(input_delay={**jittered, "policy": "in_order"})
    assert not np.array_equal(in_order["plant.x1"], constant["plant.x1"])


# -- what the controller measures ----------------------------------------------------------

_M64 = (1 << 64) - 1


def _splitmix(z: int) -> int:
    """SplitMix64's finalizer, written out again from its published constants."""
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _M64
    return z ^ (z >> 31)


def _uniform_delay(seed: int, j: int, delay: float, jitter: float) -> float:
    """Packet ``j``'s uniform delay as the channel's module docstring specifies it: draw 2
    of packet j, counter ``j 2^32 + 3``, key ``mix(seed ^ sqrt(2)'s bits)``."""
    key = _splitmix(seed ^ 0x6A09E667F3BCC909)
    u = (_splitmix((key + ((j << 32) + 3) * 0x9E3779B97F4A7C15) & _M64) >> 11) * 2.0 ** -53
    return delay + jitter * u


def test_the_measurement_is_what_the_channel_makes_of_the_plants_output():
    tables = {"meas_delay": {"distribution": "uniform", "jitter": 0.35,
                             "loss_model": "bernoulli", "loss": 0.3, "seed": 11}}
    loop = _loop(**tables)
    seen = (Port("meas_delay", "y1"), Port("meas_delay", "y2"), Port("meas_delay", "stamp"))
    res = api.run(loop.replace(recorded=loop.recorded + seen), engine="inprocess")
    t, x1, x2 = res.times, res["plant.x1"], res["plant.x2"]
    y1, y2, stamp = res["meas_delay.y1"], res["meas_delay.y2"], res["meas_delay.stamp"]
    h = loop.h
    line = ChannelLine(Channel(delay=0.36, distribution="uniform", jitter=0.35,
                               loss_model="bernoulli", loss=0.3, seed=11), 2, h, [1.0, 0.0])
    for k in range(len(t)):
        (a, b), s = line.step([x1[k], x2[k]])
        assert (a, b, s) == (y1[k], y2[k], stamp[k]), k
    # independently of ChannelLine: each value shown is the plant's output at its stamp
    # (or the history x0 before the first packet), at least r old
    for k in range(len(t)):
        if stamp[k] < 0 or (stamp[k] == 0 and y1[k] == 1.0 and k * h < 0.36):
            assert (y1[k], y2[k]) == (1.0, 0.0)
            continue
        i = round(stamp[k] / h)
        assert (y1[k], y2[k]) == (x1[i], x2[i]), k
        assert t[k] - stamp[k] >= 0.36 - 1e-9


def test_each_packets_delay_is_the_draw_the_module_specifies():
    """Independently of ``delaycomp.maths.channel``: with ``drop_stale`` and no loss the
    value shown at step k is the newest packet that has arrived, packet j (sent at step j)
    arriving ``ceil(d_j / h)`` steps later, ``d_j`` from the draw written out here."""
    loop = _loop(meas_delay={"distribution": "uniform", "jitter": 0.35,
                             "policy": "drop_stale", "seed": 11})
    res = api.run(loop.replace(recorded=(*loop.recorded, Port("meas_delay", "stamp"))),
                  engine="inprocess")
    h, stamp = loop.h, res["meas_delay.stamp"]
    K = len(stamp)
    arrival = [j + math.ceil(_uniform_delay(11, j, 0.36, 0.35) / h - 1e-9) for j in range(K)]
    assert len({a - j for j, a in enumerate(arrival)}) > 10  # the delays do vary
    checked = 0
    for k in range(K):
        arrived = [j for j in range(k + 1) if arrival[j] <= k]
        if not arrived:
            assert stamp[k] == min(k * h - 0.36, 0.0)  # the history's stamp
            continue
        assert stamp[k] == max(arrived) * h, k
        checked += 1
    assert checked > 500


# -- the API --------------------------------------------------------------------------------

def test_api_lti_takes_the_channels_as_the_loop_file_does():
    meas = Channel(distribution="uniform", jitter=0.35, loss_model="bernoulli", loss=0.3,
                   seed=11)
    inp = Channel(distribution="uniform", jitter=0.25, loss_model="bernoulli", loss=0.3,
                  seed=5)
    loop = api.lti(BASE["plant"]["A"], BASE["plant"]["B"], BASE["controller"]["K"],
                   T=0.2, r=0.36, tau=0.4, N=20, x0=[1.0, 0.0], name="dbl",
                   meas_channel=meas, input_channel=inp)
    assert loop == _loop(**LOSSY)
    # it keeps its loop-file data: built again with overrides (a sweep's points)
    again = LoopData.of(loop).loop(["meas_delay.seed=12"])
    assert again.by_role("meas_delay").parameters["seed"] == 12
    with pytest.raises(ParameterError, match="meas_channel"):
        api.lti([[1.0]], [[1.0]], [[-2.0]], T=1.0, x0=[1.0], meas_channel={"delay": 0.1})


def test_api_model_takes_the_channels():
    from .conftest import REPO

    loop = api.model(REPO / "docs" / "examples" / "cart.py", T=0.5, r=0.3, tau=0.5, N=50,
                     x0=[1.0, 0.0], input_channel=Channel(distribution="uniform",
                                                          jitter=0.1, seed=2))
    inp = loop.by_role("input_delay")
    assert inp.source.kind == "channel" and inp.parameters["delay"] == 0.5
    assert loop.by_role("meas_delay").source.kind == "delay"


# -- commands that do not take a channel yet ------------------------------------------------

@pytest.mark.parametrize("argv,what", [
    (["critical-delay", "{loop}"], "`critical-delay`"),
    (["sweep", "{loop}", "--grid", "r=0.36:0.4:2", "--stop-time", "1", "--out",
      "{tmp}/s.csv"], "the batch engine"),
    (["sweep", "{loop}", "--grid", "r=0.36:0.4:2", "--exact", "--out", "{tmp}/s.csv"],
     "`sweep --exact`"),
])
def test_a_command_without_channels_refuses_one_in_one_line(tmp_path, capsys, argv, what):
    path = _toml(tmp_path / "net.toml", **LOSSY)
    argv = [a.format(loop=path, tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    assert "[meas_delay] channel is not supported by " + what in err, err


def test_a_sweep_runs_the_channel_in_process(tmp_path):
    """The run-based metrics of a sweep take the channel as it is (seeds as an axis; the
    two seeds' measurements part at t = 1.38 s, the plant's states at 2.06 s)."""
    path = _toml(tmp_path / "net.toml", **LOSSY)
    assert main(["sweep", str(path), "--grid", "meas_delay.seed=1:2:2", "--engine",
                 "inprocess", "--stop-time", "4", "--out", str(tmp_path / "s.csv")]) == 0
    rows = (tmp_path / "s.csv").read_text().splitlines()
    assert rows[0].startswith("meas_delay.seed,") and len(rows) == 3
    assert rows[1].split(",")[3] != rows[2].split(",")[3]  # the seeds: final norms differ


def test_api_refusals():
    loop = _loop(**LOSSY)
    with pytest.raises(ParameterError, match=r"\[meas_delay\] channel is not supported"):
        api.critical_delay(loop)


def test_the_reference_tables_channel_defaults_are_the_readers():
    """Each ``channel`` key of ``loopkeys.TABLE`` whose default is a value (in backticks),
    written out, builds the same loop as an empty table; ``delay`` written out as the
    loop's true delay does too."""
    from delaycomp.system.loopkeys import TABLE

    written = {}
    for e in TABLE:
        if e.table != "channel":
            continue
        assert e.default is None  # a key written out makes the table: no DEFAULTS entry
        text = e.shown
        if text.startswith("`") and text.endswith("`") and text.count("`") == 2:
            value = text.strip("`")
            written[e.key] = value.strip('"') if value.startswith('"') else (
                float(value) if "." in value else int(value))
    assert set(written) == {"distribution", "jitter", "shape", "loss_model", "loss", "p_gb",
                            "p_bg", "loss_good", "loss_bad", "policy", "seed", "period"}
    assert _loop(meas_delay=written) == _loop(meas_delay={})
    assert _loop(meas_delay={"delay": 0.36}) == _loop(meas_delay={})
    assert _loop(meas_delay={"seed": 1}) != _loop(meas_delay={})
