"""What the sampled controllers' slaves share on top of ``delaycomp.fmu.slave.TableSlave``.

A controller samples at ``t0 + iT`` and holds its output over each period: whether a step
ends on the next sampling instant (``ends_on_sample``) or reaches a padded output's
instant (``reaches_release``), the ``held_sample`` parameter and the input held with it
(``HeldSampleMixin``: the LTI and model controllers), and the time-stamp controllers'
stamp, proposal, commit and checked hidden state (``StampedSlaveMixin``). The delay, the
channel and the plants sample nothing and do not import this module.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NoReturn

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Variability

from delaycomp.errors import ParameterError
from delaycomp.fmu.slave import (
    check_inputs,
    state_count,
    state_number,
    state_refused,
    state_rows,
    state_vector,
)
from delaycomp.maths.grid import GRID_RTOL, drift

_EPS4 = 4 * float(np.finfo(float).eps)  # round-off allowance on sampling-instant times


def ends_on_sample(current_time: float, step_size: float, t0: float, T: float,
                   next_index: int) -> bool:
    """Does the step ``[t, t + h]`` of a controller sampling at ``t0 + i T`` end on its next
    instant ``t0 + next_index T`` (up to the grid's tolerance and the drift of a host's
    clock, ``t += h``: ``delaycomp.maths.grid.drift``)? ``ParameterError`` where it passes
    over it."""
    t_end = current_time + step_size
    t_sample = t0 + next_index * T
    tol = GRID_RTOL * T + max(_EPS4 * abs(t_end), drift(t_end, step_size, t0))
    if t_end > t_sample + tol:
        raise ParameterError(f"step [{current_time!r}, {t_end!r}] is not allowed: it passes "
                             f"over the sampling instant {t_sample!r}; steps must end on "
                             "t0 + iT")
    return abs(t_end - t_sample) <= tol


def reaches_release(current_time: float, step_size: float, t0: float, T: float,
                    release: float) -> bool:
    """Does the step ``[t, t + h]`` of a padded controller (``pad``, Remark 3.3(b)) reach
    the instant ``release = t_i + padding`` at which ``u_i`` reaches its output (up to the
    tolerance of ``ends_on_sample``)? ``ParameterError`` where it passes over it."""
    t_end = current_time + step_size
    tol = GRID_RTOL * T + max(_EPS4 * abs(t_end), drift(t_end, step_size, t0))
    if t_end > release + tol:
        raise ParameterError(f"step [{current_time!r}, {t_end!r}] is not allowed: it passes "
                             f"over the padded output's instant {release!r}; steps must end "
                             "on t0 + iT + padding")
    return t_end >= release - tol


class HeldSampleMixin:
    """The controllers' ``held_sample`` parameter (a ``TableSlave`` with input ``y``).

    With ``held_sample = true`` a controller samples at ``t_i`` the input held over the step
    that ended at ``t_i`` (before the first step: the input set at ``t0``), so its output
    does not depend on its input at the same instant. This is for masters that read every
    output right after ``doStep`` and only then set inputs (libcosim, Ecos, the container
    of ``delaycomp export-loop``); the loop shortens the measurement delay by one step to
    compensate. The held input is hidden state (saved with the FMU state).
    """

    # what the TableSlave it is mixed into provides (annotations for the type checker only)
    y: np.ndarray
    held_sample: bool
    register_variable: Callable[..., None]

    def register_held_sample(self) -> None:
        """Register the Boolean parameter ``held_sample`` (default false); call it from the
        slave's ``__init__``."""
        self.held_sample = False
        self._y_held: np.ndarray | None = None  # the input held over the step that just ended
        self.register_variable(Boolean(
            "held_sample", causality=Fmi2Causality.parameter,
            variability=Fmi2Variability.fixed, getter=lambda: self.held_sample,
            setter=lambda v: setattr(self, "held_sample", bool(v)),
            description="sample at t0 + iT the input held over the step ending there (no "
                        "direct feedthrough; for masters that read outputs before setting "
                        "inputs)"))

    def _sample(self) -> np.ndarray:
        """The measurement sampled now: the input, or (``held_sample``) the held one."""
        if self.held_sample and self._y_held is not None:
            return self._y_held
        return self.y

    def _hold(self) -> bool:
        """At the end of a step: keep the input it was held at (``held_sample`` only)."""
        if self.held_sample:
            self._y_held = self.y.copy()
            return True
        return False

    def _held_state(self) -> list | None:
        return None if self._y_held is None else self._y_held.tolist()

    def _checked_held(self, held) -> list | None:
        """The held input of a restored state: null, or (held_sample) n finite numbers."""
        if held is None:
            return None
        if not self.held_sample:
            raise state_refused("hidden.y_held", held, "null with held_sample = false")
        return state_vector("hidden.y_held", held, len(self.y))

    def _restore_held(self, held: list | None) -> None:
        self._y_held = None if held is None else np.array(held, dtype=float)


class StampedSlaveMixin(HeldSampleMixin):
    """What the time-stamp controllers' slaves share (``delaycomp.maths.stamped``): the
    input ``stamp``, the sample and its stamp held (``held_sample``), the output proposed
    at a sampling instant and committed by the step that leaves it, and the hidden state
    checked field by field when restored.

    The slave sets ``n``, ``m``, ``y`` (n numbers), registers ``T``, ``tau``, ``age_max``
    and ``mode`` with ``register_timing`` and its inputs, the stamp and its outputs with
    ``register_ports``, and builds ``ctrl`` (a
    ``_StampedCore``: ``StampedController`` or ``StampedModelController``) in ``_setup``
    before calling ``_reset_stamps``.
    """

    # what the TableSlave it is mixed into provides (annotations for the type checker only)
    n: int
    m: int
    T: float
    t0: float
    u0: np.ndarray
    ctrl: Any
    error: str | None
    input_names: list
    output_names: list
    mode: str
    _refuse: Callable[[str], None]
    fail: Callable[[str], NoReturn]
    real_input: Callable[..., None]
    real_output: Callable[..., None]
    parameter: Callable[..., None]
    string_parameter: Callable[..., None]

    def register_timing(self, mode_text: str) -> None:
        """Register the parameters ``T``, ``tau``, ``age_max`` and the String ``mode``
        (compensated or uncompensated, ``mode_text`` its description), in that order, with
        the slave's attributes of those names."""
        from delaycomp.maths.lti import MODES

        for name, text in (
            ("T", "sampling period [s], > 0"),
            ("tau", "input delay [s], >= 0 (constant: a delay, or a channel's play-out "
                    "buffer)"),
            ("age_max", "the largest age of a sample the predictor uses [s], >= 0: it sizes "
                        "the stored inputs; an older sample is not used"),
        ):
            self.parameter(name, (lambda a=name: getattr(self, a)),
                           (lambda v, a=name: setattr(self, a, v)), text)
        self.string_parameter("mode", lambda: self.mode, lambda v: setattr(self, "mode", v),
                              mode_text, MODES)

    def register_ports(self, inputs: list[str], texts: list[str], outputs: list[str]) -> None:
        """Register the measurement inputs ``inputs`` (described by ``texts``), the Real
        input ``stamp`` and the held outputs ``outputs``, in that order; sets
        ``input_names`` (the inputs, then ``stamp``) and ``output_names``."""
        self.input_names = [*inputs, "stamp"]
        self.output_names = list(outputs)
        for i, (name, text) in enumerate(zip(inputs, texts)):
            self.real_input(name, (lambda i=i: float(self.y[i])), self.y_setter(i), text)
        self._register_stamp()
        for j, name in enumerate(self.output_names):
            self.real_output(name, (lambda j=j: float(self._output()[j])),
                             "control, held over each sampling period",
                             depends_on=self.input_names,
                             variability=Fmi2Variability.discrete)

    def _register_stamp(self) -> None:
        """Register the Real input ``stamp`` (after the measurement inputs)."""
        self.stamp = 0.0
        self._stamp_held: float | None = None
        self._at_sample = True
        self._proposal: np.ndarray | None = None

        def set_stamp(v):
            self.stamp = v
            self._proposal = None

        self.real_input("stamp", lambda: self.stamp, set_stamp,
                        "the time [s] the sample y was taken (a channel's stamp), <= t")

    def y_setter(self, i: int) -> Callable[[float], None]:
        """The setter of the measurement input ``i`` (a new value drops the proposal)."""
        def setter(v):
            self.y[i] = v
            self._proposal = None
        return setter

    def _reset_stamps(self) -> None:
        """At initialization: at a sampling instant, nothing proposed or held."""
        self._at_sample = True
        self._proposal = None
        self._y_held = None
        self._stamp_held = None

    def _sampled(self) -> tuple[np.ndarray, float]:
        """The sample and its stamp read now (``held_sample``: those held over the step
        that just ended)."""
        if self.held_sample and self._stamp_held is not None:
            return self._sample(), self._stamp_held
        return self.y, self.stamp

    def _hidden_state(self) -> dict:
        ctrl = self.ctrl
        assert ctrl is not None  # saved only when initialized
        return {"ctrl": ctrl.get_state(), "at_sample": self._at_sample,
                "y_held": self._held_state(), "stamp_held": self._stamp_held}

    def _restore_hidden(self, hidden: dict) -> None:
        core = self.ctrl
        assert core is not None  # called after _setup() built it
        ctrl = hidden.get("ctrl")
        if not isinstance(ctrl, dict):
            raise state_refused("hidden.ctrl", ctrl, "an object (held, history, i, z, stamp)")
        z, stamp = ctrl.get("z"), ctrl.get("stamp")
        checked: dict[str, Any] = {
            "held": state_vector("hidden.ctrl.held", ctrl.get("held"), self.m, False),
            "history": state_rows("hidden.ctrl.history", ctrl.get("history"),
                                  core.L, self.m, False),
            "i": state_count("hidden.ctrl.i", ctrl.get("i")),
            "z": None if z is None else state_vector("hidden.ctrl.z", z, self.n),
            "stamp": None if stamp is None else state_number("hidden.ctrl.stamp", stamp)}
        if (z is None) != (checked["i"] == 0):
            raise state_refused("hidden.ctrl.z", z, "null exactly before the first instant")
        if stamp is not None and not stamp <= self.t0 + checked["i"] * self.T:
            raise state_refused("hidden.ctrl.stamp", stamp, "a time before the instant")
        at_sample = hidden.get("at_sample")
        if not isinstance(at_sample, bool):
            raise state_refused("hidden.at_sample", at_sample, "true or false")
        y_held = self._checked_held(hidden.get("y_held"))
        stamp_held = hidden.get("stamp_held")
        if (stamp_held is None) != (y_held is None):
            raise state_refused("hidden.stamp_held", stamp_held, "given with y_held")
        if stamp_held is not None:
            stamp_held = state_number("hidden.stamp_held", stamp_held)
        core.set_state(checked)
        self._at_sample = at_sample
        self._restore_held(y_held)
        self._stamp_held = stamp_held
        self._proposal = None

    def _output(self) -> np.ndarray:
        ctrl = self.ctrl
        if ctrl is None:
            return self.u0
        if not self._at_sample:
            return ctrl.held
        if self._proposal is None:
            y, stamp = self._sampled()
            t = self.t0 + ctrl.i * self.T
            try:
                with np.errstate(all="ignore"):  # checked below
                    u = ctrl.propose(y, stamp)
            except ValueError as exc:  # a stamp from the future
                if self.error is None:
                    self._refuse(str(exc))
                return ctrl.held
            except Exception as exc:  # noqa: BLE001 - a model's solve or feedback failed
                if self.error is None:
                    self._refuse(f"computing the control at t = {t!r} failed: "
                                 f"{type(exc).__name__}: {exc}")
                return ctrl.held
            if not np.all(np.isfinite(u)) and np.all(np.isfinite(y)) and self.error is None:
                self._refuse(f"control {self.output_names} = {u.tolist()} at t = {t!r} is "
                             "not allowed: must be finite (the feedback diverged: overflow)")
            self._proposal = u
        return self._proposal

    def _step(self, current_time: float, step_size: float) -> None:
        check_inputs(self.input_names, [*self.y, self.stamp], current_time)
        ctrl = self.ctrl
        assert ctrl is not None  # steps only when initialized
        if self._at_sample:
            y, stamp = self._sampled()
            try:
                u = self._proposal if self._proposal is not None else ctrl.propose(y, stamp)
                ctrl.commit(u, y, stamp)
            except ValueError as exc:  # a stamp from the future
                self.fail(str(exc))
            self._proposal = None
        self._at_sample = ends_on_sample(current_time, step_size, self.t0, self.T, ctrl.i)
        if self._hold():
            self._stamp_held = self.stamp
            self._proposal = None
