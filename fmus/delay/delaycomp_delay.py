"""FMU slave: transport delay ``y(t) = u(t - delay)`` on n channels.

The maths is ``delaycomp.maths.delayline.DelayLine``. See README.md beside this file.
"""

from __future__ import annotations

import math

from delaycomp.fmu.slave import (
    TableSlave,
    check_finite,
    check_inputs,
    is_roundoff_step,
    state_count,
    state_number,
    state_refused,
    state_rows,
)
from delaycomp.maths.delayline import DelayLine, steps_of
from delaycomp.maths.grid import grid_step, same_step
from delaycomp.names import indexed


class DelaycompDelay(TableSlave):
    """Transport delay, exact for signals piecewise constant on the communication grid."""

    description = "transport delay y(t) = u(t - delay), initial history u0 on [t0 - delay, t0)"
    fp_guarded = True  # a step copies values: no arithmetic that could overflow

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        n = int(self.config["n"])
        self.n = n
        #: structural: False builds the variant for delays of at least one communication
        #: step, whose outputs declare no dependence on the inputs (no direct feedthrough)
        self.feedthrough = bool(self.config.get("feedthrough", True))
        self.delay = 0.0
        self.u0 = [0.0] * n
        self.u = [0.0] * n
        self.line: DelayLine | None = None  # made at the first step, when h is known
        self._h: float | None = None  # the line's step, set with it
        self.parameter("delay", lambda: self.delay, lambda v: setattr(self, "delay", v),
                       "delay [s], >= 0, an integer multiple of the communication step")
        for i in range(n):
            get, put = (lambda i=i: self.u0[i]), (lambda v, i=i: self.u0.__setitem__(i, v))
            self.parameter(f"u0[{i + 1}]", get, put,
                           "input history, constant on [t0 - delay, t0)")
        self.input_names = indexed("u", n)
        self.output_names = indexed("y", n)
        for i, name in enumerate(self.input_names):
            self.real_input(name, (lambda i=i: self.u[i]),
                            (lambda v, i=i: self.u.__setitem__(i, v)), "delayed signal, input")
        for i, (name, src) in enumerate(zip(self.output_names, self.input_names)):
            # The feedthrough variant declares the output dependent on its input (with
            # delay = 0 the output is the input); the other one refuses delay = 0, so its
            # output at t_k depends only on inputs of earlier grid points.
            self.real_output(name, (lambda i=i: self._output()[i]), "u(t - delay)",
                             depends_on=(src,) if self.feedthrough else ())

    def _setup(self):
        check_finite("delay", self.delay)
        if self.delay < 0:
            self.fail(f"delay = {self.delay!r} is not allowed: must be >= 0")
        if not self.feedthrough and self.delay == 0:
            self.fail("delay = 0.0 is not allowed: this delay FMU is built without direct "
                      "feedthrough (feedthrough = false), so delay must be >= one "
                      "communication step")
        for i, v in enumerate(self.u0):
            check_finite(f"u0[{i + 1}]", v)
        self.line = None
        self._h = None

    def _hidden_state(self) -> dict:
        if self.line is None:
            return {"h": None}
        return {"h": self._h, "D": self.line.D, "buffer": self.line.get_state()}

    def _restore_hidden(self, hidden: dict) -> None:
        if hidden == {"h": None}:
            return  # no line yet: before the first step
        h = state_number("hidden.h", hidden.get("h"), positive=True)
        try:
            D = steps_of(self.delay, h)
        except ValueError as exc:
            raise state_refused("hidden.h", h, f"a step of this delay ({exc})") from None
        if D == 0 and not self.feedthrough:
            raise state_refused("hidden.h", h, f"at most delay = {self.delay!r} (this delay "
                                "FMU is built without direct feedthrough)")
        state_count("hidden.D", hidden.get("D"), D)
        buffer = state_rows("hidden.buffer", hidden.get("buffer"), D, self.n)
        self.line = DelayLine(self.n, D, self.u0)
        self.line.set_state(buffer)
        self._h = h

    def _output(self):
        if self.line is not None:
            return self.line.output(self.u)
        return tuple(self.u) if self.delay == 0 else tuple(self.u0)

    def _step(self, t: float, step_size: float) -> None:
        if not (math.isfinite(step_size) and step_size > 0):
            self.fail(f"step size {step_size!r} at t = {t!r} is not allowed: must be a finite "
                      "number > 0")
        if self.line is None:
            try:
                D = steps_of(self.delay, step_size)
            except ValueError as exc:  # names the delay, its value and what is allowed
                self.fail(str(exc))
            if D == 0 and not self.feedthrough:
                self.fail(f"delay = {self.delay!r} is not allowed: this delay FMU is built "
                          "without direct feedthrough (feedthrough = false), so delay must be "
                          f">= one communication step, {step_size!r}")
            self.line = DelayLine(self.n, D, self.u0)
            self._h = step_size
        else:
            assert self._h is not None  # set with the line
            if is_roundoff_step(step_size, self._h):
                return  # the master's round-off (fmuslave.ROUNDOFF_STEP_FRACTION): nothing moves
            if not (same_step(step_size, self._h, t)
                    or grid_step(t, step_size, self._h, self.t0)):
                # round-off is not another step size: libcosim keeps time in integer
                # nanoseconds and passes t_{k+1} - t_k, off by ~1e-12 relative at t = 60 s; a
                # host whose clock drifts (t += h) ends its last step on the stop time
                # (grid_step)
                self.fail(f"step size {step_size!r} is not allowed: this delay runs on a "
                          f"fixed communication step, {self._h!r}")
        check_inputs(self.input_names, self.u, t)
        self.line.push(self.u)
