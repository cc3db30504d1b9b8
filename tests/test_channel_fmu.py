"""The network channel FMU (issue 29, item 1): ``fmus/delay/delaycomp_channel.py``.

Run by our master's FMU driver (``FmuComponent``, fmpy underneath): with a constant delay
and no loss it is the delay FMU, the same doubles; with jitter, loss, a period, a trace and
either policy it is ``delaycomp.maths.channel.ChannelLine`` called directly (tested on its
own in ``tests/test_channel.py``); its state restores the run; bad parameters and crafted
states are refused naming the field.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from delaycomp.fmu.build import build_fmu
from delaycomp.fmu.cache import fmu_path
from delaycomp.fmu.native import native_fmu_path
from delaycomp.maths.channel import Channel, ChannelLine
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

pytestmark = pytest.mark.fmu

H = 0.01
N_SIG = 2


def _built(impl: str) -> dict:
    """The delay and the channel for two signals, and the channel with a trace of 5, as
    Python FMUs or their native twins (``fmus/delay/channel.c``, this platform's binary),
    from the session's build caches."""
    build = fmu_path if impl == "python" else native_fmu_path
    built = {kind: build(kind, {"n": N_SIG}) for kind in ("channel", "delay")}
    built["traced"] = build("channel", {"n": N_SIG, "L": 5})
    return built


@pytest.fixture(scope="module", params=["python", "native"])
def fmus(request):
    """Each test that takes it runs on the Python FMUs and on their native twins."""
    return _built(request.param)


@pytest.fixture(scope="module")
def python_fmus():
    return _built("python")


@pytest.fixture(scope="module")
def native_fmus():
    return _built("native")


def _inputs(steps: int) -> np.ndarray:
    return np.random.default_rng(3).normal(size=(steps, N_SIG))


def _drive(path, params: dict, u: np.ndarray, outputs: list[str], state_at: int | None = None):
    """Rows of ``outputs`` at t_0 .. t_steps (inputs of t_k set before reading), and the
    state taken after ``state_at`` steps."""
    comp = FmuComponent("c", path)
    comp.setup(0.0, len(u) * H, params)
    write, read = comp.writer([f"u{i + 1}" for i in range(N_SIG)]), comp.reader(outputs)
    write(list(u[0]))
    comp.initialize()
    rows, state = [], None
    for k in range(len(u)):
        write(list(u[k]))
        rows.append(read())
        if k == state_at:
            state = comp.get_state()
        comp.do_step(k * H, H)
    comp.terminate()
    return np.array(rows), state


@pytest.mark.parametrize("delay", [0.0, 0.01, 0.36])
def test_a_constant_channel_is_the_delay_fmu(fmus, delay):
    """The same doubles as the delay FMU at every step; the stamp is ``t - delay``."""
    u = _inputs(120)
    u0 = {"u0[1]": 0.5, "u0[2]": -1.5}
    want, _ = _drive(fmus["delay"], {"delay": delay, **u0}, u, ["y1", "y2"])
    got, _ = _drive(fmus["channel"], {"delay": delay, **u0}, u, ["y1", "y2", "stamp"])
    assert np.array_equal(got[:, :2], want)
    t = np.arange(len(u)) * H
    assert np.allclose(got[:, 2], t - delay, rtol=0, atol=1e-15)  # t_(k-D), or t_k - delay


CASES = {
    "uniform-bernoulli": {"delay": 0.02, "distribution": "uniform", "jitter": 0.3,
                          "loss_model": "bernoulli", "loss": 0.3, "seed": 1},
    "gamma-gilbert-period": {"delay": 0.01, "distribution": "gamma", "jitter": 0.2,
                             "shape": 2.0, "max_delay": 0.6,
                             "loss_model": "gilbert_elliott", "p_gb": 0.1, "p_bg": 0.4,
                             "seed": 5, "period": 0.03, "policy": "drop_stale"},
    "exponential": {"distribution": "exponential", "jitter": 0.05, "max_delay": 0.2,
                    "seed": 12},
    "playout-gilbert-period": {"delay": 0.02, "distribution": "uniform", "jitter": 0.3,
                               "loss_model": "gilbert_elliott", "p_gb": 0.2, "p_bg": 0.5,
                               "period": 0.02, "policy": "playout", "seed": 8},
    "trace": {"delay": 0.03, "distribution": "trace", "trace[1]": 0.03, "trace[2]": 0.2,
              "trace[3]": -1.0, "trace[4]": 0.07, "trace[5]": 0.11, "seed": 6,
              "policy": "drop_stale"},
}


def _channel(params: dict) -> Channel:
    """The maths' channel of FMU parameters (a negative trace entry: NaN, lost)."""
    fields = {k: v for k, v in params.items() if not k.startswith(("u0", "trace["))}
    trace = [v for k, v in params.items() if k.startswith("trace[")]
    if trace:
        fields["trace"] = tuple(math.nan if d < 0 else d for d in trace)
    return Channel(**fields)


@pytest.mark.parametrize("case", list(CASES))
def test_the_fmu_is_the_channel_line(fmus, case):
    """Values and stamps at every step as ``ChannelLine`` gives them for the same
    parameters and inputs, exactly; and the run holds losses and reordering."""
    params = {**CASES[case], "u0[1]": 3.0, "u0[2]": -3.0}
    u = _inputs(300)
    got, _ = _drive(fmus["traced" if case == "trace" else "channel"], params, u,
                    ["y1", "y2", "stamp"])
    line = ChannelLine(_channel(params), N_SIG, H, [3.0, -3.0])
    want = np.array([[*v, s] for v, s in (line.step(u[k]) for k in range(len(u)))])
    assert np.array_equal(got, want)
    age = np.arange(len(u)) * H - got[:, 2]
    assert len(np.unique(np.round(age, 9))) > 3  # the delays vary


def test_the_state_restores_the_run(fmus):
    params = {**CASES["gamma-gilbert-period"], "u0[1]": 1.0}
    u = _inputs(200)
    whole, state = _drive(fmus["channel"], params, u, ["y1", "y2", "stamp"], state_at=80)
    comp = FmuComponent("again", fmus["channel"])
    comp.setup(0.0, len(u) * H, params)
    write, read = comp.writer(["u1", "u2"]), comp.reader(["y1", "y2", "stamp"])
    write(list(u[0]))
    comp.initialize()
    comp.set_state(state)
    comp.do_step(80 * H, H)
    rows = []
    for k in range(81, len(u)):
        write(list(u[k]))
        rows.append(read())
        comp.do_step(k * H, H)
    comp.terminate()
    assert np.array_equal(np.array(rows), whole[81:])


@pytest.mark.parametrize("params, message", [
    ({"distribution": "exponential", "jitter": 0.1},
     "max_delay is required for distribution = 'exponential'"),
    ({"loss_model": "bernoulli", "loss": 1.5},
     "loss = 1.5 is not allowed: must be a finite number >= 0.0 and <= 1.0"),
    ({"distribution": "trace"}, "distribution = 'trace' is not allowed: this channel FMU is "
                                "built without a trace (L = 0): build it with the trace's "
                                "length L >= 1"),
    ({"seed": -4}, "seed = -4 is not allowed: must be an integer in 0 .. 2147483647"),
    ({"period": 0.015}, "period = 0.015 is not allowed: must be a multiple of the "
                        "communication step 0.01"),
    ({"distribution": "uniform", "delay": 0.5, "jitter": 1e5},
     "delay + jitter = 100000.5 is not allowed: must be at most 1000000 steps of the "
     "communication step 0.01 (it needs 1e+07)"),
    ({"distribution": "pareto"}, "distribution = 'pareto' is not allowed: must be one of"),
])
def test_a_bad_parameter_is_refused_naming_it(fmus, params, message):
    """At initialization (the parameters alone) or at the first step (the period against
    the step): refused, the FMU's message naming the parameter and what is allowed."""
    from fmpy.fmi1 import FMICallException

    comp = FmuComponent("bad", fmus["channel"])
    with pytest.raises((FmuRefused, FMICallException)):
        comp.setup(0.0, 1.0, params)
        comp.initialize()
        comp.do_step(0.0, H)
    assert comp.last_message is not None and message in comp.last_message, comp.messages


@pytest.mark.parametrize("mutate, message", [
    (lambda line: line["inflight"][0].__setitem__(2, 10**6),
     "FMU state is not allowed: hidden.line.inflight[0].ready = 1000000: must be in"),
    (lambda line: line["inflight"][0].__setitem__(1, 7),
     "FMU state is not allowed: hidden.line.inflight[0].sent = 7: must be"),
    (lambda line: line["inflight"].reverse(),
     "FMU state is not allowed: hidden.line.inflight = "),
    (lambda line: line["inflight"][0].__setitem__(4, [1.0]),
     "FMU state is not allowed: hidden.line.inflight[0].values = [1.0]: must be a list of 2 "
     "finite numbers"),
    (lambda line: line.__setitem__("bad", 1),
     "FMU state is not allowed: hidden.line.bad = 1: must be true or false"),
    (lambda line: line.__setitem__("inflight", [[k, k, k, False, [0.0, 0.0]]
                                                for k in range(99, 160)]),
     "FMU state is not allowed: hidden.line.inflight = "),
])
def test_a_crafted_state_is_refused_naming_the_field(python_fmus, mutate, message):
    """The channel's part of a state (its packets in flight, the one shown, the chain),
    altered: refused naming the field and what it must be, never restored."""
    import json

    fmus = python_fmus
    params = dict(CASES["uniform-bernoulli"])
    _, state = _drive(fmus["channel"], params, _inputs(100), ["y1"], state_at=60)
    data = json.loads(state)
    assert len(data["hidden"]["line"]["inflight"]) >= 2
    mutate(data["hidden"]["line"])
    comp = FmuComponent("crafted", fmus["channel"])
    comp.setup(0.0, 1.0, params)
    comp.initialize()
    with pytest.raises(FmuRefused) as info:
        comp.set_state(json.dumps(data).encode())
    assert message in str(info.value), str(info.value)


def _packet(snap, buf, slot: int) -> list:
    """Slot ``slot`` of a native state's packet buffer (0: the shown packet, 1 ..: those
    in flight): seq, sent, ready, lost, values (fmus/delay/channel.h)."""
    width = 4 + N_SIG
    return buf[slot * width:(slot + 1) * width]


def _set(buf, slot: int, field: int, value: float) -> None:
    buf[slot * (4 + N_SIG) + field] = value


def _swap(buf, a: int, b: int) -> None:
    w = 4 + N_SIG
    buf[a * w:(a + 1) * w], buf[b * w:(b + 1) * w] = buf[b * w:(b + 1) * w], buf[a * w:(a + 1) * w]


@pytest.mark.parametrize("mutate, message", [
    (lambda m, b: _set(b, 1, 2, 10.0**6), "inflight[0].ready = 1000000.0: must be an integer in"),
    (lambda m, b: _set(b, 1, 1, 7.0), "inflight[0].sent = 7.0: must be "),
    (lambda m, b: _swap(b, 1, 2), "inflight[1].seq = "),
    (lambda m, b: _set(b, 1, 4, math.nan), "inflight[0].values[0] = nan: must be a finite number"),
    (lambda m, b: _set(b, 1, 3, 0.5), "inflight[0].lost = 0.5: must be 0.0 or 1.0"),
    (lambda m, b: setattr(m, "bad", 2), "bad = 2: must be 0 or 1"),
    (lambda m, b: setattr(m, "count", 99), "count = 99: must be in 0 .. "),
    (lambda m, b: setattr(m, "Q", 3), "Q = 3: must be "),
    (lambda m, b: setattr(m, "k", -5), "k = -5: must be >= 0"),
    (lambda m, b: _set(b, 0, 0, 1.5), "current.seq = 1.5: must be an integer >= 0"),
    # Q = steps_up(0.02 + 0.3, 0.01) = 32 steps, so 32 + 3 slots in flight: the last one
    (lambda m, b: _set(b, 35, 0, 1.0), "inflight[34][0] = 1.0: must be 0.0 (beyond count)"),
    (lambda m, b: b.append(0.0), "nbuf = "),
])
def test_a_crafted_native_state_is_refused_naming_the_field(native_fmus, mutate, message):
    """The native twin's state (``ModelData`` and the packet buffer, laid out as
    ``tests/native_state.py`` mirrors them), altered: refused naming the field, the
    instance left as it was."""
    from fmpy.fmi1 import FMICallException

    from .native_state import decode, encode, layout_of

    fmu = native_fmus["channel"]
    params = dict(CASES["uniform-bernoulli"])
    _, state = _drive(fmu, params, _inputs(100), ["y1"], state_at=60)
    snap, buf = decode(layout_of(fmu), state)
    assert snap.d.m.count >= 2 and snap.d.m.has_current == 1
    buf = list(buf)
    mutate(snap.d.m, buf)
    comp = FmuComponent("crafted", fmu)
    comp.setup(0.0, 1.0, params)
    comp.initialize()
    before = comp.get_state()
    with pytest.raises(FMICallException):
        comp.set_state(encode(snap, buf))
    text = comp.messages[-1].split("] ", 1)[-1]
    assert text.startswith("fmi2DeSerializeFMUstate: FMU state is not allowed: " + message), text
    assert comp.get_state() == before
    comp.terminate()


def test_the_native_state_restores_into_another_instance(native_fmus, python_fmus):
    """A native state taken mid-run and restored into a fresh instance goes on as the run
    did, and that run is the Python FMU's (the twins agree after a restore too)."""
    params = {**CASES["gamma-gilbert-period"], "u0[1]": 1.0}
    u = _inputs(200)
    whole, state = _drive(native_fmus["channel"], params, u, ["y1", "y2", "stamp"], state_at=80)
    python, _ = _drive(python_fmus["channel"], params, u, ["y1", "y2", "stamp"])
    assert np.array_equal(whole, python)
    comp = FmuComponent("again", native_fmus["channel"])
    comp.setup(0.0, len(u) * H, params)
    write, read = comp.writer(["u1", "u2"]), comp.reader(["y1", "y2", "stamp"])
    write(list(u[0]))
    comp.initialize()
    comp.set_state(state)
    comp.do_step(80 * H, H)
    rows = []
    for k in range(81, len(u)):
        write(list(u[k]))
        rows.append(read())
        comp.do_step(k * H, H)
    comp.terminate()
    assert np.array_equal(np.array(rows), whole[81:])


@pytest.mark.parametrize("params, message", [
    ({"distribution": "trace", "delay": 0.2, "trace[2]": 0.1},
     "trace[2] = 0.1 is not allowed: must be a delay >= delay = 0.2 [s], or negative (a lost "
     "packet)"),
    ({"trace[4]": float("inf")}, "trace[4] = inf is not allowed: must be a finite number"),
])
def test_a_bad_trace_entry_is_refused_naming_it(fmus, params, message):
    """The trace of a build with L = 5: an entry shorter than ``delay`` (where the trace is
    used), or not finite (always)."""
    from fmpy.fmi1 import FMICallException

    full = {f"trace[{i}]": 0.3 for i in range(1, 6)} | params
    comp = FmuComponent("bad", fmus["traced"])
    with pytest.raises((FmuRefused, FMICallException)):
        comp.setup(0.0, 1.0, full)
        comp.initialize()
    assert comp.last_message is not None and message in comp.last_message, comp.messages


def test_the_trace_entries_are_parameters_of_the_build(fmus, tmp_path):
    """``L`` is the build's: ``trace[1..L]`` Real parameters (none for L = 0), and a
    length out of range is refused before anything is built."""
    from fmpy import read_model_description

    names = [v.name for v in read_model_description(str(fmus["traced"])).modelVariables]
    assert [n for n in names if n.startswith("trace")] == [f"trace[{i}]" for i in range(1, 6)]
    plain = [v.name for v in read_model_description(str(fmus["channel"])).modelVariables]
    assert not [n for n in plain if n.startswith("trace")]
    for bad in (-1, 10_001, 2.0):
        with pytest.raises(ValueError, match=r"L = .* is not allowed: must be an integer "
                                             r"from 0 to 10000"):
            build_fmu("channel", tmp_path / "x", {"n": 1, "L": bad})


@pytest.fixture(scope="module")
def fmi3_fmus():
    """The native channel as FMI 3.0 FMUs: with a trace of 5 and without one."""
    return {"channel": native_fmu_path("channel", {"n": N_SIG}, fmi=3),
            "traced": native_fmu_path("channel", {"n": N_SIG, "L": 5}, fmi=3)}


@pytest.mark.parametrize("case", list(CASES))
def test_the_fmi3_channel_is_the_fmi2_one(fmi3_fmus, native_fmus, case):
    """``build --fmi 3``: the same C behind the FMI 3.0 layer, the same doubles at every
    step; ``trace`` an array sized by the structural parameter ``L`` (a build without a
    trace has neither), ``u0`` by ``n``; fmpy's validation passes."""
    from fmpy.validation import validate_fmu

    which = "traced" if case == "trace" else "channel"
    params = {**CASES[case], "u0[1]": 3.0, "u0[2]": -3.0}
    u = _inputs(300)
    two, _ = _drive(native_fmus[which], params, u, ["y1", "y2", "stamp"])
    three, _ = _drive(fmi3_fmus[which], params, u, ["y1", "y2", "stamp"])
    assert np.array_equal(three, two)
    assert validate_fmu(str(fmi3_fmus[which])) == []


def test_the_fmi3_trace_is_an_array_sized_by_L(fmi3_fmus):
    import xml.etree.ElementTree as ET
    import zipfile

    def variables(fmu):
        with zipfile.ZipFile(fmu) as zf:
            root = ET.fromstring(zf.read("modelDescription.xml"))
        return {v.get("name"): v for v in root.find("ModelVariables")}

    traced = variables(fmi3_fmus["traced"])
    assert (traced["L"].tag, traced["L"].get("causality"), traced["L"].get("start")) == (
        "UInt64", "structuralParameter", "5")
    assert [d.get("valueReference") for d in traced["trace"].findall("Dimension")] == [
        traced["L"].get("valueReference")]
    assert [d.get("valueReference") for d in traced["u0"].findall("Dimension")] == [
        traced["n"].get("valueReference")]
    plain = variables(fmi3_fmus["channel"])
    assert "trace" not in plain and "L" not in plain and "u0" in plain
