"""The master's ordering and timing, with in-process mock slaves (no FMI)."""

from __future__ import annotations

import pytest

from delaycomp.orchestrator.master import Connection, Master, Recorder, SimulationError


class Mock:
    """A slave with one input ``in``, one output ``out`` and a rule for both."""

    def __init__(self, name, feedthrough, out, step=None):
        self.name = name
        self.input_names = ["in"]
        self.output_names = ["out"]
        self.feedthrough_outputs = frozenset({"out"}) if feedthrough else frozenset()
        self._out, self._step = out, step
        self.u = 0.0
        self.state = 0.0
        self.calls = []
        self.last_message = None

    def setup(self, start_time, stop_time, parameters):
        self.state = parameters.get("x0", 0.0)

    def initialize(self):
        pass

    def set_inputs(self, names, values):
        self.u = values[0]

    def get_outputs(self, names):
        return [self._out(self)]

    def do_step(self, t, h):
        self.calls.append(t)
        if self._step:
            self._step(self, h)

    def terminate(self):
        pass


def integrator(name="plant"):
    # x_{k+1} = x_k + h u_k; output x (no feedthrough)
    return Mock(name, False, lambda m: m.state, lambda m, h: setattr(m, "state", m.state + h * m.u))


def gain(name, g):
    return Mock(name, True, lambda m: g * m.u)


def loop(*names):
    return [Connection.parse(f"{a}.out -> {b}.in") for a, b in zip(names, names[1:] + names[:1])]


def test_feedthrough_chain_adds_no_delay():
    """plant -> g1 -> g2 -> plant with gains is x_{k+1} = (1 - h a b) x_k exactly."""
    comps = [integrator(), gain("g1", -2.0), gain("g2", 1.5)]
    # list the components in an order that is *not* the signal order
    master = Master([comps[2], comps[0], comps[1]], loop("plant", "g1", "g2"), T=1.0, N=10)
    rec = Recorder(master, [("plant", "out"), ("g2", "out")])
    master.add_observer(rec)
    master.setup(1.0, {"plant": {"x0": 1.0}})
    master.initialize()
    master.run_until(10)
    x = 1.0
    for k in range(len(rec.times)):
        assert rec.rows[k][0] == pytest.approx(x, rel=1e-15)
        assert rec.rows[k][1] == pytest.approx(-3.0 * x, rel=1e-15)  # same instant, no lag
        x = x + 0.1 * (-3.0 * x)


def test_ticks_are_integers_and_hit_sampling_instants_exactly():
    comps = [integrator(), gain("g", -1.0)]
    master = Master(comps, loop("plant", "g"), T=0.1, N=3, t0=0.0)
    master.setup(1.0, {})
    master.initialize()
    master.run_until(3 * 1000)
    assert master.time_of(3 * 1000) == 1000 * 0.1
    assert all(master.time_of(3 * i) == i * 0.1 for i in range(1000))
    assert comps[0].calls[3 * 500] == 500 * 0.1


def test_algebraic_loop_is_refused():
    with pytest.raises(ValueError, match="algebraic loop"):
        Master([gain("a", 1.0), gain("b", 1.0)], loop("a", "b"), T=1.0, N=1)


def test_algebraic_loop_names_its_members_only():
    """a -> b -> c -> a is a cycle; d hangs off it (feedthrough too, but not in the cycle)
    and the plant feeds nothing into it: the message names exactly the cycle, in order."""
    comps = [integrator(), gain("a", 1.0), gain("b", 1.0), gain("c", 1.0), gain("d", 1.0)]
    cons = [*loop("a", "b", "c"), Connection.parse("c.out -> d.in"),
            Connection.parse("d.out -> plant.in")]
    with pytest.raises(ValueError, match=r"algebraic loop a -> b -> c -> a: ") as err:
        Master(comps, cons, T=1.0, N=1)
    assert "d" not in str(err.value).split(":")[0].split()


def test_a_delay_without_feedthrough_breaks_the_cycle():
    """A plant with direct feedthrough (y = x + u) in a loop with a gain: refused; with a
    one-step delay (no feedthrough) in between it runs, and the trajectory is the delayed
    recursion x_{k+1} = x_k + h u_k, u_k = g (x_{k-1} + u_{k-1}), computed here by hand."""
    def ft_plant():
        return Mock("plant", True, lambda m: m.state + m.u,
                    lambda m, h: setattr(m, "state", m.state + h * m.u))

    with pytest.raises(ValueError, match="algebraic loop"):
        Master([ft_plant(), gain("g", -1.0)], loop("plant", "g"), T=1.0, N=1)

    def delay():  # y_k = u_{k-1}, y_0 = 0
        m = Mock("delay", False, lambda m: m.state)
        m._step = lambda m, h: setattr(m, "state", m.u)
        return m

    master = Master([ft_plant(), delay(), gain("g", -0.5)], loop("plant", "delay", "g"),
                    T=1.0, N=10)
    rec = Recorder(master, [("plant", "out")])
    master.add_observer(rec)
    master.setup(1.0, {"plant": {"x0": 1.0}})
    master.initialize()
    master.run_until(10)
    x, d = 1.0, 0.0  # plant state, delay output
    for k in range(len(rec.times)):
        u = -0.5 * d
        y = x + u
        assert rec.rows[k][0] == pytest.approx(y, rel=1e-15)
        x, d = x + 0.1 * u, y


@pytest.mark.parametrize("text,match", [
    ("plant.out -> nobody.in", "no component"),
    ("plant.nope -> g.in", "no output"),
])
def test_bad_connections_are_named(text, match):
    with pytest.raises(ValueError, match=match):
        Master([integrator(), gain("g", 1.0)], [Connection.parse(text)], T=1.0, N=1)


@pytest.mark.parametrize("N", [0, -1, 1.5])
def test_N_must_be_a_positive_integer(N):
    with pytest.raises(ValueError, match="N must be a positive integer"):
        Master([integrator()], [], T=1.0, N=N)


def test_failure_names_component_and_time_and_keeps_results():
    def boom(m, h):
        if m.calls[-1] >= 0.5:
            m.last_message = "state is not finite"
            raise RuntimeError("doStep failed")
        m.state += h * m.u

    bad = Mock("plant", False, lambda m: m.state, boom)
    master = Master([bad, gain("g", -1.0)], loop("plant", "g"), T=1.0, N=10)
    rec = Recorder(master, [("plant", "out")])
    master.add_observer(rec)
    master.setup(1.0, {"plant": {"x0": 1.0}})
    master.initialize()
    with pytest.raises(SimulationError, match=r"plant failed at t = 0.5: state is not finite"):
        master.run_until(10)
    assert len(rec.times) == 6  # t = 0 .. 0.5 recorded
