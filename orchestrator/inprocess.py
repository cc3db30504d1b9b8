"""The project's slaves as master components in this process, without the FMI layer.

``SlaveComponent`` instantiates the very slave class an FMU wraps (the modules under
``fmus/``, on the maths of ``delaycomp``) and calls its variable getters and setters and
its ``do_step`` directly: no fmpy, no ctypes, no embedded interpreter. The master and the
step order are the same as with FMUs, so a run gives the same numbers (tested to 1e-12 on
every scenario) at a fraction of the cost: this is the engine for sweeps and tuning.

Failures follow the FMU semantics of ``delaycomp.fmu.slave``: a slave that refuses its
parameters logs an error at initialization (``initialize`` raises with that message), and a
step it cannot take returns ``False`` (``do_step`` raises with the logged reason).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from pythonfmu.enums import Fmi2Causality

from delaycomp.errors import DelaycompError
from delaycomp.fmu.slaves import slave_class
from delaycomp.orchestrator.master import ComponentBase

if TYPE_CHECKING:
    from pythonfmu.variables import ScalarVariable


class SlaveRefused(DelaycompError, RuntimeError):
    """The slave logged an error (bad parameter, or a step it cannot take)."""


class SlaveComponent(ComponentBase):
    """One slave instance, with the master's component protocol (as ``FmuComponent``)."""

    def __init__(self, name: str, kind: str, config: dict, fp_guarded: bool = False):
        """``fp_guarded``: the caller runs every step under ``np.errstate(all="ignore")``
        (as ``delaycomp.orchestrator.simulate.run_loop`` does), so the slave need not."""
        self.name = name
        self._cls, self._config = slave_class(kind, config)
        self.messages: list[str] = []
        self.last_message: str | None = None
        self.worst_status = 0
        self.slave = self._cls(instance_name=name, resources=None, config=self._config)
        if fp_guarded:  # else the slave class's own setting stands
            self.slave.fp_guarded = True
        by_causality: dict[Fmi2Causality, list[ScalarVariable]] = {}
        for v in self.slave.vars.values():
            by_causality.setdefault(v.causality, []).append(v)
        self._vars = {v.name: v for v in self.slave.vars.values()}
        self.input_names = [v.name for v in by_causality.get(Fmi2Causality.input, [])]
        self.output_names = [v.name for v in by_causality.get(Fmi2Causality.output, [])]
        deps = self.slave.dependencies
        self.feedthrough_outputs = frozenset(o for o in self.output_names if deps.get(o))
        self._readers: dict[tuple[str, ...], object] = {}
        self._writers: dict[tuple[str, ...], object] = {}

    def _drain(self) -> None:
        queue = self.slave.log_queue
        for msg in queue:
            self._note(int(msg.status), msg.msg)
        queue.clear()

    # -- Component protocol ------------------------------------------------------------
    def setup(self, start_time: float, stop_time: float, parameters: dict) -> None:
        """Set up the slave's experiment from ``start_time``, enter initialization mode and
        set the ``parameters`` (by variable name, converted to the variable's type)."""
        self.slave.setup_experiment(start_time, stop_time, None)
        self.slave.enter_initialization_mode()
        for pname, value in parameters.items():
            var = self._var(pname)
            kind = type(var).__name__
            convert = {"Real": float, "Integer": int, "Boolean": bool}.get(kind, str)
            var.setter(convert(value))
        self._drain()

    def initialize(self) -> None:
        """Leave initialization mode; raise ``SlaveRefused`` if the slave logged an
        error (it refused its parameters)."""
        self.slave.exit_initialization_mode()
        self._drain()
        if self.worst_status >= 3:
            raise SlaveRefused(self.last_message or "the slave logged an error")

    def reader(self, names: Sequence[str]):
        """``() -> [values]`` of the outputs ``names``: the master's hot path."""
        getters = [self._var(n).getter for n in names]
        slave = self.slave

        def refused():
            self._drain()
            return SlaveRefused(self.last_message or slave.error)

        if len(getters) == 1:
            g = getters[0]

            def read():
                values = [g()]
                if slave.error is not None:  # it refused while computing: do not use it
                    raise refused()
                return values
            return read

        def read_all():
            values = [g() for g in getters]
            if slave.error is not None:  # it refused while computing them: do not use them
                raise refused()
            return values
        return read_all

    def writer(self, names: Sequence[str]):
        """``(values) -> None`` setting the inputs ``names``: the master's hot path."""
        setters = [self._var(n).setter for n in names]
        if len(setters) == 1:
            s = setters[0]
            return lambda values: s(values[0])

        def write(values):
            for s, v in zip(setters, values):
                s(v)
        return write

    def do_step(self, t: float, h: float) -> None:
        """Step the slave from ``t`` to ``t + h``; raise ``SlaveRefused`` with the
        logged reason if it refuses."""
        if not self.slave.do_step(t, h):
            self._drain()
            raise SlaveRefused(self.last_message or "the slave refused to step")

    def get_state(self) -> bytes:
        """The slave's complete state, serialized as its FMU would serialize it."""
        data = self.slave._fmu_state_to_bytes(self.slave._get_fmu_state())
        self._drain()
        if self.worst_status >= 3:
            raise SlaveRefused(self.last_message or "saving the state failed")
        return data

    def set_state(self, data: bytes) -> None:
        """Restore a state from ``get_state``; raise ``SlaveRefused`` if the slave
        refuses it."""
        self.slave._set_fmu_state(self.slave._fmu_state_from_bytes(data))
        self._drain()
        if self.worst_status >= 3:
            raise SlaveRefused(self.last_message or "restoring the state failed")

    def terminate(self) -> None:
        """Terminate the slave (its ``terminate``, as ``fmi2Terminate`` would) and collect the
        messages it logged."""
        if self.slave is not None:
            self.slave.terminate()
            self._drain()
