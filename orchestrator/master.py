"""A small, exact fixed-step co-simulation master (Gauss-Seidel along the signal chain).

Lifecycle (after libcosim's algorithm): ``Master.setup`` instantiates and sets
parameters, ``Master.initialize`` leaves initialization mode, ``Master.step``
advances one base step, ``Master.terminate`` ends and frees everything. Results go to
observers (``Recorder``), kept apart from the stepping.

Time is an integer count ``k`` of base steps ``h = T / N``; the master never accumulates
``t += h``. The time of tick ``k`` is ``t0 + (k // N) T + (k % N) T / N``, so every
sampling instant ``t0 + i T`` is hit exactly as the controllers compute it.

Exactness. At every tick the master

1. reads the outputs of components without direct feedthrough (their outputs at ``t_k``
   do not depend on inputs at ``t_k``: the plant);
2. visits the components with direct feedthrough in topological order, each time setting
   its inputs from outputs already at ``t_k`` and then reading its outputs (delay lines,
   controller);
3. sets the inputs of the components of step 1;
4. hands the values at ``t_k`` to the observers, then steps every component from ``t_k`` to
   ``t_{k+1}``.

So a signal never waits a communication step at a connection: the controller sampling at
``t_i`` receives ``x(t_i - r)`` and the plant on ``[t_k, t_{k+1})`` receives
``u(t_k - tau)``. An algebraic loop (a cycle through feedthrough components only) is
refused at setup.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from operator import itemgetter
from typing import Protocol, cast

from delaycomp.errors import DelaycompError
from delaycomp.maths.grid import tick_time
from delaycomp.orchestrator.interrupts import interrupt_held
from delaycomp.system.loop import Connection  # the one Connection: Port -> Port


def feedthrough_order(feed: set[str], edges: Iterable[tuple[str, str]]) -> list[str]:
    """The components ``feed`` (those with direct feedthrough) in topological order of
    the connections ``edges`` (``(src, dst)`` component names; Kahn's algorithm, ties by
    name): the order in which the master visits them within a tick. Components on an
    algebraic loop are left out (the caller refuses it).

    >>> feedthrough_order({"ctrl", "delay_y", "delay_u"},
    ...                   [("plant", "delay_y"), ("delay_y", "ctrl"), ("ctrl", "delay_u"),
    ...                    ("delay_u", "plant")])
    ['delay_y', 'ctrl', 'delay_u']
    """
    edges = list(edges)
    preds = {n: {src for src, dst in edges if dst == n and src in feed} for n in feed}
    order: list[str] = []
    ready = sorted(n for n in feed if not preds[n])
    while ready:
        n = ready.pop(0)
        order.append(n)
        for m in sorted(feed):
            if n in preds[m]:
                preds[m].discard(n)
                if not preds[m] and m not in order and m not in ready:
                    ready.append(m)
    return order


class SimulationError(DelaycompError, RuntimeError):
    """A component failed; the message names it, the time and the reason.

    ``instance`` is the failing component's name (``None`` where no one component is to
    blame, as when several fail to terminate)."""

    def __init__(self, message: str, instance: str | None = None):
        super().__init__(message)
        self.instance = instance


class Component(Protocol):
    """What the master needs of a component (an FMU, or a mock in tests)."""

    name: str
    input_names: Sequence[str]
    output_names: Sequence[str]
    #: names of the outputs that depend on inputs at the same instant
    feedthrough_outputs: frozenset[str]

    def setup(self, start_time: float, stop_time: float, parameters: dict) -> None:
        """Instantiate for the run from ``start_time`` to ``stop_time``, enter
        initialization mode and set the ``parameters`` (values by variable name)."""

    def initialize(self) -> None:
        """Leave initialization mode: the component is ready to step."""

    def set_inputs(self, names: Sequence[str], values: Sequence[float]) -> None:
        """Set the inputs ``names`` to ``values`` (in the same order)."""

    def get_outputs(self, names: Sequence[str]) -> list[float]:
        """The current values of the outputs ``names``."""

    def do_step(self, t: float, h: float) -> None:
        """Advance from ``t`` to ``t + h``; raise if the component cannot."""

    def terminate(self) -> None:
        """End the run and free the component."""

    # Optional, for the hot path: ``reader(names) -> (() -> values)`` and
    # ``writer(names) -> ((values) -> None)``, bound once at construction; without them the
    # master wraps ``get_outputs`` / ``set_inputs``. A wrapper that must see every value
    # (a recorder of inputs) sets both to None.
    # Optional: ``runs_python`` (bool), whether stepping it runs Python code in this
    # interpreter; ``delaycomp.orchestrator.simulate.run_loop`` keeps BLAS on one
    # thread only then. Without it a component is taken to run Python.


class StatefulComponent(Component, Protocol):
    """A component whose state can be saved and restored (``Master.get_state``)."""

    def get_state(self) -> bytes:
        """The component's complete state, serialized."""

    def set_state(self, data: bytes) -> None:
        """Restore a state from ``get_state``."""


#: FMI status names, by value
STATUS_NAMES = ("ok", "warning", "discard", "error", "fatal", "pending")


class ComponentBase:
    """What the project's components (FMUs, in-process slaves) share: variable lookup,
    log bookkeeping, and ``get_outputs`` / ``set_inputs`` over their ``reader`` and
    ``writer`` (one bound callable per name list, made once and cached)."""

    name: str
    _vars: dict
    _readers: dict
    _writers: dict
    messages: list
    last_message: str | None
    worst_status: int
    #: whether stepping it runs Python code in this interpreter (and so this numpy); a
    #: component that does not know says True
    runs_python: bool = True
    #: ``reader(names) -> (() -> values)`` and ``writer(names) -> ((values) -> None)``, the
    #: hot-path accessors that every subclass defines
    reader: Callable[[Sequence[str]], Callable[[], list[float]]]
    writer: Callable[[Sequence[str]], Callable[[Sequence[float]], None]]

    def _var(self, name: str):
        try:
            return self._vars[name]
        except KeyError:
            raise ValueError(f"{self.name}: no variable named {name!r}") from None

    def _note(self, status: int, text: str) -> None:
        """Record a logged message; the first discard/error/fatal one names the cause."""
        label = STATUS_NAMES[status] if 0 <= status < len(STATUS_NAMES) else status
        self.messages.append(f"[{label}] {text}")
        if status >= 2 and self.last_message is None:
            self.last_message = text
        self.worst_status = max(self.worst_status, status)

    def get_outputs(self, names: Sequence[str]) -> list[float]:
        """The current values of the outputs ``names`` (through a cached ``reader``)."""
        key = tuple(names)
        read = self._readers.get(key)
        if read is None:
            read = self._readers[key] = self.reader(names)
        return read()

    def set_inputs(self, names: Sequence[str], values: Sequence[float]) -> None:
        """Set the inputs ``names`` to ``values`` (through a cached ``writer``)."""
        key = tuple(names)
        write = self._writers.get(key)
        if write is None:
            write = self._writers[key] = self.writer(names)
        write(values)


@dataclass
class _Plan:
    """Per-tick work precomputed at setup: the hot loop only indexes lists."""

    # (component, output names, slots) for components read first (no feedthrough)
    heads: list = field(default_factory=list)
    # (component, input names, input slots, output names, output slots), topological
    chain: list = field(default_factory=list)
    # (component, input names, input slots) set last
    tails: list = field(default_factory=list)


def _gather(slots: Sequence[int]):
    """``values -> [values[i] for i in slots]`` as one C call (None for no slots)."""
    if not slots:
        return None
    if len(slots) == 1:
        i = slots[0]
        return lambda values: (values[i],)
    return itemgetter(*slots)


def _find_cycle(names: set[str], connections: Sequence[Connection]) -> list[str]:
    """One cycle among ``names`` (each has a predecessor among them), as
    ``[a, b, ..., a]`` in signal order; the components left over by a topological sort
    always contain one."""
    succ = {n: sorted({c.dst.instance for c in connections
                       if c.src.instance == n and c.dst.instance in names})
            for n in names}
    pred = {n: sorted({c.src.instance for c in connections
                       if c.dst.instance == n and c.src.instance in names})
            for n in names}
    # walk backwards along predecessors until a component repeats: that closes a cycle
    path: list[str] = []
    seen: dict[str, int] = {}
    node = min(names)
    while node not in seen:
        seen[node] = len(path)
        path.append(node)
        node = pred[node][0]
    cycle = path[seen[node]:][::-1]  # backwards walk reversed: signal order
    first = cycle.index(min(cycle))
    cycle = cycle[first:] + cycle[:first]  # starting from its first name, for stable text
    assert all(b in succ[a] for a, b in zip(cycle, cycle[1:] + cycle[:1]))
    return [*cycle, cycle[0]]



class Master:
    """Fixed-step master over integer ticks of ``h = T / N``.

    Parameters
    ----------
    components:
        the components, by name; stepped every base step.
    connections:
        the signal connections.
    T, N:
        sampling period and base steps per period (``h = T / N``).
    t0:
        start time.
    """

    def __init__(self, components: Iterable[Component], connections: Iterable[Connection],
                 T: float, N: int, t0: float = 0.0):
        if not (isinstance(N, int) and N >= 1):
            raise ValueError(f"N must be a positive integer, got {N!r}")
        if not T > 0:
            raise ValueError(f"T must be > 0, got {T!r}")
        self.components = {c.name: c for c in components}
        self.connections = list(connections)
        self.T, self.N, self.t0 = float(T), N, float(t0)
        self.h = self.T / N
        self.k = 0
        self._plan = self._make_plan()
        self._slots: list[float] = [0.0] * len(self._slot_of)
        self._observers: list = []
        # the hot loop's work as bound methods and slot lists, precomputed once
        self._stepping = list(self.components.values())
        self._heads = [(self._getter(c, outs), oslots) for c, outs, oslots in self._plan.heads]
        self._chain = [(self._setter(c, ins), _gather(islots), self._getter(c, outs), oslots)
                       for c, ins, islots, outs, oslots in self._plan.chain]
        self._tails = [(self._setter(c, ins), _gather(islots))
                       for c, ins, islots in self._plan.tails]

    @staticmethod
    def _getter(c, names):
        """``() -> values`` of the outputs ``names`` (the component's own if it has one)."""
        names = list(names)
        if getattr(c, "reader", None) is not None:
            return c.reader(names)
        get_outputs = c.get_outputs
        return lambda: get_outputs(names)

    @staticmethod
    def _setter(c, names):
        """``(values) -> None`` setting the inputs ``names``."""
        names = list(names)
        if getattr(c, "writer", None) is not None:
            return c.writer(names)
        set_inputs = c.set_inputs
        return lambda values: set_inputs(names, values)

    # -- planning ----------------------------------------------------------------------
    def _make_plan(self) -> _Plan:
        comps = self.components
        self._slot_of: dict[tuple[str, str], int] = {}
        for c in comps.values():
            for name in c.output_names:
                self._slot_of[(c.name, name)] = len(self._slot_of)
        sources: dict[str, list[tuple[str, int]]] = {name: [] for name in comps}
        seen_inputs = set()
        for con in self.connections:
            for port, kind in ((con.src, "output"), (con.dst, "input")):
                inst, var = port.instance, port.variable
                if inst not in comps:
                    raise ValueError(f"connection {con}: no component named {inst!r}")
                names = comps[inst].output_names if kind == "output" else comps[inst].input_names
                if var not in names:
                    raise ValueError(f"connection {con}: {inst} has no {kind} {var!r}")
            if con.dst in seen_inputs:
                raise ValueError(f"input {con.dst} is connected twice")
            seen_inputs.add(con.dst)
            slot = self._slot_of[(con.src.instance, con.src.variable)]
            sources[con.dst.instance].append((con.dst.variable, slot))

        feed = {n for n, c in comps.items() if c.feedthrough_outputs}
        order = feedthrough_order(feed, ((con.src.instance, con.dst.instance)
                                         for con in self.connections))
        if len(order) != len(feed):
            cycle = _find_cycle(feed - set(order), self.connections)
            raise ValueError(f"algebraic loop {' -> '.join(cycle)}: every component in it "
                             "has direct feedthrough (a delay of at least one base step, "
                             "built without feedthrough, would break it)")

        plan = _Plan()
        for name, c in comps.items():
            outs = list(c.output_names)
            if name not in feed:
                plan.heads.append((c, outs, [self._slot_of[(name, o)] for o in outs]))
                ins = sources[name]
                if ins:
                    plan.tails.append((c, [v for v, _ in ins], [s for _, s in ins]))
        for name in order:
            c = comps[name]
            ins = sources[name]
            outs = list(c.output_names)
            plan.chain.append((c, [v for v, _ in ins], [s for _, s in ins], outs,
                               [self._slot_of[(name, o)] for o in outs]))
        return plan

    # -- lifecycle ---------------------------------------------------------------------
    def time_of(self, k: int) -> float:
        """Time of tick ``k``, exact at every sampling instant (``tick_time``)."""
        return tick_time(k, self.t0, self.T, self.h, self.N)

    def add_observer(self, observer) -> None:
        """Hand ``observer.record(k, t, values)`` the output values of every tick from now
        on (``values[slot(instance, variable)]``, see ``Recorder``)."""
        self._observers.append(observer.record)

    def setup(self, stop_time: float, parameters: dict[str, dict]) -> None:
        """Set up every component for the run from ``t0`` to ``stop_time``, with its
        ``parameters`` (by component name; values by variable name)."""
        for name, c in self.components.items():
            self._guard(c, 0, c.setup, self.t0, stop_time, parameters.get(name, {}))

    def initialize(self) -> None:
        """Initialize every component, go to tick 0 and propagate its values (observers
        see tick 0)."""
        for c in self.components.values():
            self._guard(c, 0, c.initialize)
        self.k = 0
        self._propagate()

    def get_state(self) -> dict:
        """The tick and every component's state (components need ``get_state``)."""
        return {"k": self.k, "components": {
            name: self._guard(c, self.k, cast(StatefulComponent, c).get_state)
            for name, c in self.components.items()}}

    def set_state(self, state: dict) -> None:
        """Go back (or forward) to a state from ``get_state``; observers are not told
        again about the restored tick (they saw it when it was first reached)."""
        self.k = int(state["k"])
        for name, c in self.components.items():
            self._guard(c, self.k, cast(StatefulComponent, c).set_state,
                        state["components"][name])
        self._propagate(record=False)

    def _guard(self, comp, k, fn, *args):
        try:
            return fn(*args)
        except SimulationError:
            raise
        except Exception as exc:
            reason = getattr(comp, "last_message", None) or str(exc) or type(exc).__name__
            raise SimulationError(f"{comp.name} failed at t = {self.time_of(k):.12g}: {reason}",
                                  comp.name) from exc

    def _propagate(self, record: bool = True) -> None:
        """Bring every output and input to the values of the current tick."""
        slots = self._slots
        k = self.k
        try:
            for get, oslots in self._heads:
                for s, v in zip(oslots, get()):
                    slots[s] = v
            for put, gather, get, oslots in self._chain:
                if gather is not None:
                    put(gather(slots))
                for s, v in zip(oslots, get()):
                    slots[s] = v
            for put, gather in self._tails:
                put(gather(slots))
        except Exception as exc:  # noqa: BLE001 - reported with the component's reason
            self.propagation_failed(exc, k)
        if not math.isfinite(sum(slots)):  # NaN or inf among the outputs (one sum a tick)
            self.refuse_nonfinite(k)
        if not record or not self._observers:
            return
        t = self.time_of(k)
        for rec in self._observers:
            rec(k, t, slots)

    def _nonfinite(self) -> tuple[str, str, float] | None:
        """The first output that is NaN or infinite: ``(instance, variable, value)``."""
        slots = self._slots
        for (inst, var), s in self._slot_of.items():
            if not math.isfinite(slots[s]):
                return inst, var, slots[s]
        return None

    def refuse_nonfinite(self, k: int) -> None:
        """Stop the run where an output is NaN or infinite (a plant FMU that broke down,
        at any tick, the last included), naming it and the time; a sum that overflowed
        over finite outputs passes."""
        bad = self._nonfinite()
        if bad is not None:
            inst, var, value = bad
            raise SimulationError(f"{inst} failed at t = {self.time_of(k):.12g}: its output "
                                  f"{var} = {value!r} is not allowed: must be finite", inst)

    def propagation_failed(self, exc: Exception, k: int):
        """Raise the ``SimulationError`` of a read or write at tick ``k`` that raised
        ``exc`` (a non-finite value already in the vector is blamed first)."""
        self.refuse_nonfinite(k)  # a component refusing a NaN input: blame the source
        culprit = next((c for c in self.components.values()
                        if getattr(c, "last_message", None)), None)
        name = culprit.name if culprit else "a component"
        reason = getattr(culprit, "last_message", None) or str(exc)
        raise SimulationError(f"{name} failed at t = {self.time_of(k):.12g}: {reason}",
                              culprit.name if culprit else None) from exc

    def step(self) -> None:
        """Advance every component from ``t_k`` to ``t_{k+1}``; then propagate."""
        k = self.k
        t = self.time_of(k)
        h = self.h
        comp = None
        try:
            for comp in self._stepping:
                comp.do_step(t, h)
        except SimulationError:
            raise
        except Exception as exc:  # noqa: BLE001 - reported with the component's reason
            assert comp is not None  # the loop raised: it ran
            self.step_failed(comp, exc, t)
        self.k = k + 1
        self._propagate()

    @staticmethod
    def step_failed(comp, exc: Exception, t: float):
        """Raise the ``SimulationError`` of ``comp``'s step from ``t`` that raised
        ``exc``: its logged reason, else the exception's."""
        reason = getattr(comp, "last_message", None) or str(exc) or type(exc).__name__
        raise SimulationError(f"{comp.name} failed at t = {t:.12g}: {reason}",
                              comp.name) from exc

    # -- what a stepping core needs of the master ----------------------------------------
    @property
    def stepping(self) -> list:
        """The components in the order ``step`` steps them."""
        return list(self._stepping)

    @property
    def values(self) -> list[float]:
        """The value vector of the current tick (``slot``): every output, as last read
        (a stepping core writes its own back here)."""
        return self._slots

    def tick_plan(self) -> list[tuple[str, Component, list[str], list[int]]]:
        """One tick's propagation as the master does it, in order: ``("get", component,
        outputs, slots)`` reads the outputs into the value vector, ``("set", component,
        inputs, slots)`` sets the inputs from it. The components without feedthrough are
        read first, the feedthrough chain is set and read in topological order, the first
        ones' inputs are set last."""
        plan = self._plan
        ops: list[tuple[str, Component, list[str], list[int]]] = []
        ops += [("get", c, list(outs), list(oslots)) for c, outs, oslots in plan.heads]
        for c, ins, islots, outs, oslots in plan.chain:
            if islots:  # a component of the chain without inputs is only read
                ops.append(("set", c, list(ins), list(islots)))
            ops.append(("get", c, list(outs), list(oslots)))
        ops += [("set", c, list(ins), list(islots)) for c, ins, islots in plan.tails]
        return ops


    def run_until(self, stop_ticks: int) -> None:
        """Step until tick ``stop_ticks`` (no step if it is reached already)."""
        while self.k < stop_ticks:
            self.step()

    def terminate(self) -> None:
        """Terminate every component, all of them even if some fail; then raise
        ``SimulationError`` naming the failures, if any. Ctrl-C meanwhile is held
        until all are freed (``interrupt_held``)."""
        errors = []
        with interrupt_held():
            for c in self.components.values():
                try:
                    c.terminate()
                except Exception as exc:  # noqa: BLE001 - keep freeing the others
                    errors.append(f"{c.name}: {exc}")
        if errors:
            raise SimulationError("; ".join(errors))

    def slot(self, instance: str, variable: str) -> int:
        """Index of an output in the value vector handed to observers."""
        try:
            return self._slot_of[(instance, variable)]
        except KeyError:
            raise ValueError(f"no output {instance}.{variable}") from None


class Recorder:
    """Observer that keeps selected outputs at every ``every``-th tick, for CSV and plots.

    The components themselves keep bounded state only (docs/explanation/reliability.md); with
    ``keep=False`` so does the recorder.

    Parameters
    ----------
    master : Master
        the master whose value vector it reads.
    signals : sequence of (instance, variable)
        the recorded outputs, in column order.
    every : int
        record tick ``k`` when ``k % every == 0`` (decimation of a long run).
    sink : callable, optional
        ``sink(t, row)`` for every recorded row, as it comes (a CSV written during the
        run).
    keep : bool
        keep every recorded row in ``times`` / ``rows`` (memory grows with the
        run); with ``False`` only the last row is kept, so a streamed run stays flat.
    final : int, optional
        a tick recorded even off the decimation (the stop tick).
    """

    def __init__(self, master: Master, signals: Sequence[tuple[str, str]], every: int = 1,
                 sink=None, keep: bool = True, final: int | None = None):
        if not (isinstance(every, int) and every >= 1):
            raise ValueError(f"every = {every!r} is not allowed: must be a positive integer")
        self.names = [f"{i}.{v}" for i, v in signals]
        self._idx = [master.slot(i, v) for i, v in signals]
        self._gather = _gather(self._idx) or (lambda values: ())
        self.every = every
        self.sink = sink
        self.keep = keep
        self.final = final
        #: rows recorded so far (kept or not)
        self.count = 0
        self.times: list[float] = []
        self.rows: list[Sequence[float]] = []

    def record(self, k: int, t: float, slots: Sequence[float]) -> None:
        """Observer call for tick ``k`` at time ``t`` with the master's value vector
        ``slots``: keep (and pass to the sink) the recorded signals if the tick is due."""
        if k % self.every and k != self.final:
            return
        row = self._gather(slots)
        self.count += 1
        if self.sink is not None:
            self.sink(t, row)
        if self.keep:
            self.times.append(t)
            self.rows.append(row)
        else:
            self.times[:] = [t]
            self.rows[:] = [row]

    @property
    def slots(self) -> list[int]:
        """The recorded signals' slots in the master's value vector, in column order."""
        return list(self._idx)

    def record_block(self, times, rows) -> None:
        """Rows recorded by a stepping core in one go (their ticks were due): ``times``
        (a 1-D array) and ``rows`` (a 2-D array, one row a tick, ``slots``' columns), as ``record``
        would have kept them row by row; a sink with ``write_rows(times, rows)``
        (``CsvStream``) takes them at once, any other row by row."""
        n = len(times)
        if not n:
            return
        self.count += n
        if self.sink is not None:
            write_rows = getattr(self.sink, "write_rows", None)
            if write_rows is not None:
                write_rows(times, rows)
            else:
                for t, row in zip(times, rows):
                    self.sink(float(t), tuple(row.tolist()))
        if self.keep:
            self.times.extend(times.tolist())
            self.rows.extend(map(tuple, rows.tolist()))
        else:
            self.times[:] = [float(times[-1])]
            self.rows[:] = [tuple(rows[-1].tolist())]

    def column(self, name: str) -> list[float]:
        """The kept values of the signal ``name`` (``"instance.variable"``)."""
        j = self.names.index(name)
        return [row[j] for row in self.rows]
