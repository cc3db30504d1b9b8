"""Thin base class shared by the project's pythonfmu slaves.

It does the FMI bookkeeping that every slave of this project needs, so that each slave
module only declares its variable table and calls the maths:

1. the build configuration (dimensions, names) is read from ``delaycomp_fmu.json`` in the
   FMU's resources, written there by ``delaycomp.fmu.build``;
2. the bundled package version is checked against the one the FMU was built with
   (pythonfmu slaves share the host's ``sys.modules``: a different ``delaycomp`` already
   imported in the host would silently run other code);
3. the GUID is pinned (a UUID5 of model name, version and configuration), so that a rebuild
   of the same sources gives the same modelDescription;
3b. an optional ``start`` table in the configuration (parameter name -> value) replaces the
   slave's own defaults at registration, so the FMU's start values (in modelDescription and
   at run time) are those of one scenario: a self-contained FMU for the FMI cross-check
   (``delaycomp.verify.crosscheck``), where an importer sets no parameters;
4. the ModelStructure lists each output's dependencies on inputs (direct feedthrough),
   which pythonfmu leaves undeclared;
5. no Python exception leaves the slave for an expected fault. pythonfmu 0.7 turns every
   exception into fmi2Fatal and drops the Python object (a later fmi2Terminate crashes the
   host, and repeated fatal errors have crashed the interpreter); no exception of any
   kind (``SystemExit`` and ``KeyboardInterrupt`` from a user model included) leaves an
   FMI entry point of this class. Instead a bad parameter
   is logged with status error when initialization ends, and every later ``doStep``
   returns fmi2Discard with the reason logged; a fault during a step does the same;
6. the FMU state (``fmi2GetFMUstate`` and its serialization) holds every registered
   variable that has a setter, the start time, whether the instance is initialized, its
   error, and the hidden state of the maths objects (delay buffers, input histories,
   controller states and tick counters) that each subclass returns from ``_hidden_state``.
   The state is plain JSON (floats written with ``repr``, so a round trip is exact).

7. the FMI 2.0 call sequence is enforced (FMI 2.0, 4.2.4, the co-simulation state
   machine): a set of an output, of an unknown or mistyped value reference, of a
   parameter after ``fmi2ExitInitializationMode``, or of anything after ``fmi2Terminate``
   is refused (status error logged; the instance then refuses to step); a ``doStep``
   before initialization, after termination, with a step that is not finite and > 0, a
   time that is not finite, or a time that is not where the last step ended (time going
   backwards or jumping) returns fmi2Discard with the reason. pythonfmu 0.7 cannot return
   fmi2Error from a set call (an exception would be fmi2Fatal), so a refused set returns
   fmi2OK with the error logged, and every later ``doStep`` returns fmi2Discard;
8. an FMU state handed to the host is a small handle whose state lives in
   ``delaycomp.fmu.statehandle`` (``StateHandle``): pythonfmu 0.7's ``fmi2FreeFMUstate``
   drops one reference to the object it got and never clears the host's pointer, so a
   second free of the same state would free it twice and crash the host. Each handle is
   pinned (32 references held there), so repeated frees only lower the pin count; the
   state's data is dropped once no one but the pins holds the handle, and a freed handle
   restored later is a named refusal. Each saved state leaves its handle and pins (about
   350 bytes), kept even through the interpreter's teardown (which freed a handle freed
   twice one pin early, and then wrote into it); a state blob that is not ours (not JSON,
   another model, no data) is a named refusal too;
9. a String parameter with a fixed set of choices (``mode``, ``predictor``, a model's
   ``CHOICES``) has an Integer twin ``<name>_index`` for importers that cannot set String
   parameters (OMSimulator's command line, many SSP tools): ``0`` (its start) leaves the
   String in charge, ``k = 1 .. n`` selects the k-th choice. When initialization ends a
   nonzero index sets the String; a String changed from its start value to another choice
   than the index names is refused, as is an index outside ``0 .. n``.

Subclasses implement ``_setup()`` (check parameters, build the maths objects) and
``_step(t, h)`` (the maths of one communication step). What the sampled controllers share
on top of this base (``held_sample``, the time-stamp controllers' ports and state, the
steps' sampling instants) is ``delaycomp.fmu.sampling``.
"""

from __future__ import annotations

import json
import math
import os
import sys
import uuid
import warnings
from collections.abc import Callable, Iterable
from typing import NoReturn
from xml.etree.ElementTree import SubElement

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Initial, Fmi2Status

from delaycomp.errors import ParameterError  # the one ParameterError (DelaycompError, ValueError)
from delaycomp.fmu.statehandle import StateHandle
from delaycomp.names import CONFIG_NAME, INDEX_SUFFIX
from delaycomp.version import __version__

#: pythonfmu 0.7's runtime releases one reference to the slave module's ``__dict__`` each
#: time it instantiates the slave class (measured: a module whose dict nothing else holds
#: is freed after the first instance, and the next instantiation reads freed memory). Each
#: instance therefore pins one reference; generated slave modules also pin one at import.
_PINNED_MODULE_DICTS: list = []
_GUID_NAMESPACE = uuid.UUID("6f1c9a4e-3d52-4b7a-9e0f-d3e1a2c4b5f6")


#: a step shorter than this fraction of a slave's fixed step is the master's round-off, not
#: a step: masters that add ``h`` to their time (OMSimulator: ``t += h``) fall behind the
#: grid by ~1e-13 s and then take a sliver step to the stop time
ROUNDOFF_STEP_FRACTION = 1e-6


def _package_folder() -> str:
    """The folder of the delaycomp package loaded in this process (the first one: an FMU's
    bundled copy or an install), as the version clash names it."""
    return os.path.dirname(sys.modules["delaycomp"].__file__ or "")


def is_roundoff_step(step_size: float, h: float) -> bool:
    """Is ``step_size`` a round-off sliver of the fixed step ``h`` (a zero-length step)?"""
    return 0 < step_size <= ROUNDOFF_STEP_FRACTION * h


def check_finite(name: str, value: float) -> float:
    """Return ``value``; raise ``ParameterError`` naming ``name`` if it is not finite."""
    if not math.isfinite(value):
        raise ParameterError(f"{name} = {value!r} is not allowed: must be a finite number")
    return value


def _plain(value):
    """JSON for numpy scalars and arrays (exact: floats are written with ``repr``)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not part of an FMU state")


def check_inputs(names, values, t: float) -> None:
    """Refuse a non-finite input value, naming the input, its value and the time."""
    if all(map(math.isfinite, values)):  # the per-step path: no names needed
        return
    for name, value in zip(names, values):
        if not math.isfinite(value):
            raise ParameterError(f"input {name} = {float(value)!r} at t = {t!r} is not "
                                 "allowed: must be a finite number")


def check_model_parameters(model, values: dict) -> None:
    """Numbers finite, strings among the model's ``CHOICES`` (when it declares them)."""
    for name, value in values.items():
        if isinstance(value, str):
            allowed = model.choices.get(name)
            if allowed is not None and value not in allowed:
                raise ParameterError(f"{name} = {value!r} is not allowed: must be one of "
                                     f"{', '.join(allowed)}")
        else:
            check_finite(name, float(value))


# -- a restored FMU state, checked field by field (the native FMUs' form, item 7) ----------
def state_refused(field: str, value, expected: str) -> ParameterError:
    """The refusal of a field of a restored FMU state: ``FMU state is not allowed: <field> =
    <value>: must be <expected>`` (the value's ``repr``, cut at 80 characters)."""
    text = repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    return ParameterError(f"FMU state is not allowed: {field} = {text}: must be {expected}")


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def state_number(field: str, value, positive: bool = False) -> float:
    """A finite number (> 0 with ``positive``) of a restored state."""
    if not (_is_number(value) and math.isfinite(value) and (value > 0 or not positive)):
        raise state_refused(field, value, "a finite number" + (" > 0" if positive else ""))
    return float(value)


def state_count(field: str, value, expected: int | None = None) -> int:
    """An integer >= 0 of a restored state (``expected`` when given)."""
    if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0
            and (expected is None or value == expected)):
        raise state_refused(field, value, "an integer >= 0" if expected is None
                            else f"{expected}")
    return value


def state_flag(field: str, value) -> bool:
    """A boolean of a restored state (true or false, not a number)."""
    if not isinstance(value, bool):
        raise state_refused(field, value, "true or false")
    return value


def _numbers(value, width: int, finite: bool) -> bool:
    return (isinstance(value, list) and len(value) == width
            and all(_is_number(v) and (math.isfinite(v) or not finite) for v in value))


def state_vector(field: str, value, width: int, finite: bool = True) -> list:
    """A list of ``width`` numbers (finite where the model needs them) of a restored state."""
    if not _numbers(value, width, finite):
        raise state_refused(field, value, f"a list of {width} {'finite ' * finite}numbers")
    return value


def state_rows(field: str, value, rows: int, width: int, finite: bool = True) -> list:
    """A list of ``rows`` lists of ``width`` numbers (finite where the model needs them) of
    a restored state."""
    if not (isinstance(value, list) and len(value) == rows
            and all(_numbers(row, width, finite) for row in value)):
        raise state_refused(field, value, f"a list of {rows} lists of {width} "
                            f"{'finite ' * finite}numbers")
    return value


#: the JSON type of each variable type's values in a state
_VALUE_TYPES = {Real: "a number", Integer: "an integer", Boolean: "true or false",
                String: "a string"}


def _value_ok(var, value) -> bool:
    if isinstance(var, Real):
        return _is_number(value)
    if isinstance(var, Integer):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(var, Boolean):
        return isinstance(value, bool)
    return isinstance(value, str)


def pinned_guid(class_name: str, config: dict) -> uuid.UUID:
    """The GUID of the slave class ``class_name`` built with ``config`` (see item 3); the
    digest of the sources the configuration records (``sources``) is not part of it."""
    config = {k: v for k, v in config.items() if k != "sources"}
    key = json.dumps({"model": class_name, "config": config}, sort_keys=True)
    return uuid.uuid5(_GUID_NAMESPACE, key)


class TableSlave(Fmi2Slave):
    """Base of the project's slaves: configuration, pinned GUID, declared dependencies."""

    description = "delaycomp FMU"
    author = "delaycomp contributors"
    license = "MIT"
    version = __version__

    #: True when a step needs no ``np.errstate(all="ignore")`` of its own (1.5 us a step):
    #: the caller provides it (the in-process engine, once per run), or the slave's step
    #: does no floating-point arithmetic that could warn (the delay, the LTI controller,
    #: whose numerical work is in an output getter guarded on its own)
    fp_guarded = False

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        _PINNED_MODULE_DICTS.append(vars(sys.modules[type(self).__module__]))
        # In-process (``orchestrator.inprocess``) the configuration comes as an argument;
        # inside an FMU it is read from the resources folder.
        config = kwargs.get("config")
        self.config = dict(config) if config is not None else self._read_config()
        #: why this instance refuses to step (None while it is healthy)
        self.error: str | None = None
        #: a fault found at instantiation (version clash); survives re-initialization
        self.instantiation_error: str | None = None
        built_with = self.config.get("version")
        if built_with != __version__:
            # Raising here would be fmi2Fatal with the object dropped (see point 5): refuse
            # instead. The message reaches the host with the first FMI call after
            # fmi2Instantiate; every later initialization and step is refused.
            self.instantiation_error = (
                f"version clash: this FMU bundles delaycomp {built_with!r}, but delaycomp "
                f"{__version__!r} (from {_package_folder()}) is "
                "already loaded in this process; pythonfmu FMUs share one interpreter, so "
                "this FMU would run the other version's code. Load FMUs of one delaycomp "
                "version per process"
            )
            self._refuse(self.instantiation_error)
        self.guid = pinned_guid(type(self).__name__, self.config)
        #: output name -> names of the inputs it depends on at the same instant
        self.dependencies: dict[str, list[str]] = {}
        self.t0 = 0.0
        #: has exitInitializationMode built the maths objects?
        self.initialized = False
        #: FMI phase: instantiated, initialization, stepping, terminated
        self.phase = "instantiated"
        #: where the next doStep must start (None: not known yet)
        self.t_next: float | None = None

    def _read_config(self) -> dict:
        if self.resources is None:
            raise RuntimeError(f"{type(self).__name__}: no resources folder")
        with open(os.path.join(self.resources, CONFIG_NAME), encoding="utf-8") as fh:
            return json.load(fh)

    # -- registration helpers ----------------------------------------------------------
    def register_variable(self, var, nested: bool = True):
        """Register ``var`` with pythonfmu; a value for it in the build's ``start`` table
        (module docstring, item 3b) replaces the slave's default through its setter."""
        super().register_variable(var, nested)
        start = getattr(self, "config", {}).get("start", {})
        if var.name in start:  # a start value of this build replaces the slave's default
            var.setter(start[var.name])

    def parameter(
        self, name: str, getter: Callable[[], float], setter: Callable[[float], None],
        description: str,
    ) -> None:
        """A Real parameter ``name`` (variability fixed: set before initialization ends)."""
        self.register_variable(
            Real(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                 getter=getter, setter=setter, description=description)
        )

    def matrix_parameter(self, label: str, mat: np.ndarray, description: str) -> None:
        """Real parameters for the elements of ``mat`` (set in place): ``label[i,j]`` of a
        matrix, ``label[i]`` of a vector (1-based, row-major)."""
        def element(idx: tuple[int, ...]) -> tuple[Callable[[], float],
                                                     Callable[[float], None]]:
            def get() -> float:
                return float(mat[idx])

            def set_(v: float) -> None:
                mat[idx] = v
            return get, set_

        for idx in np.ndindex(mat.shape):
            self.parameter(f"{label}[{','.join(str(k + 1) for k in idx)}]", *element(idx),
                           description)

    def string_parameter(
        self, name: str, getter: Callable[[], str], setter: Callable[[str], None],
        description: str, choices: Iterable[str] | None = None,
    ) -> None:
        """A String parameter; with ``choices``, also its Integer twin ``<name>_index``
        (module docstring, item 7), registered right after it."""
        self.register_variable(
            String(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                   getter=getter, setter=setter, description=description)
        )
        if choices is None:
            return
        choices = tuple(choices)
        box = [0]
        if not hasattr(self, "_choice_twins"):
            self._choice_twins: dict = {}
        # the String's start value, after a build's start table (register_variable) applied
        self._choice_twins[name] = (choices, getter(), getter, setter, box)
        listed = ", ".join(f"{k} = {c}" for k, c in enumerate(choices, 1))
        self.register_variable(Integer(
            f"{name}{INDEX_SUFFIX}", causality=Fmi2Causality.parameter,
            variability=Fmi2Variability.fixed, getter=lambda: box[0],
            setter=lambda v: box.__setitem__(0, int(v)),
            description=f"{name} as an Integer, for importers without String parameters: "
                        f"0 = as {name} says, {listed}"))

    def _resolve_choice_twins(self) -> None:
        """Apply each nonzero ``<name>_index`` to its String (module docstring, item 7)."""
        for name, (choices, start, getter, setter, box) in getattr(
                self, "_choice_twins", {}).items():
            k = box[0]
            if k == 0:
                continue
            if not 1 <= k <= len(choices):
                raise ParameterError(
                    f"{name}{INDEX_SUFFIX} = {k} is not allowed: must be 0 (as {name} says) "
                    f"or 1 .. {len(choices)} ({', '.join(choices)})")
            current = getter()
            if current not in (start, choices[k - 1]):
                raise ParameterError(
                    f"{name} = {current!r} and {name}{INDEX_SUFFIX} = {k} "
                    f"({choices[k - 1]!r}) disagree: set one of them")
            setter(choices[k - 1])

    def model_parameters(self, values: dict, defaults: dict,
                         choices: dict | None = None) -> None:
        """One FMU parameter per model parameter (Real for numbers, String for strings,
        with its Integer twin where ``choices`` lists its values), stored in ``values``."""
        for name, default in defaults.items():
            values[name] = default if isinstance(default, str) else float(default)
            get, put = (lambda n=name: values[n]), (lambda v, n=name: values.__setitem__(n, v))
            if isinstance(default, str):
                self.string_parameter(name, get, put, "model parameter",
                                      (choices or {}).get(name))
            else:
                self.parameter(name, get, put, "model parameter")

    def real_input(self, name: str, getter, setter, description: str) -> None:
        """A continuous Real input ``name``."""
        self.register_variable(
            Real(name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                 getter=getter, setter=setter, description=description)
        )

    def real_output(
        self, name: str, getter, description: str, depends_on: Iterable[str] = (),
        variability: Fmi2Variability = Fmi2Variability.continuous,
    ) -> None:
        """A Real output ``name`` (initial calculated) that depends at the same instant on
        the inputs ``depends_on`` (its ModelStructure dependencies, item 4)."""
        self.register_variable(
            Real(name, causality=Fmi2Causality.output, variability=variability,
                 initial=Fmi2Initial.calculated, getter=getter, description=description)
        )
        self.dependencies[name] = list(depends_on)

    def fail(self, message: str) -> NoReturn:
        """Abandon ``_setup`` or ``_step`` with ``message`` (logged by the caller)."""
        raise ParameterError(message)

    def _refuse(self, message: str) -> None:
        self.error = message
        self.log(message, Fmi2Status.error)

    # -- FMI entry points ----------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time, tolerance):
        """fmi2SetupExperiment: keep the start time ``t0`` (stop time and tolerance are not
        used); refused outside the instantiated phase or for a time that is not finite."""
        try:
            if self.phase != "instantiated":
                self._refuse(f"fmi2SetupExperiment is not allowed in the {self.phase} "
                             "phase: only after fmi2Instantiate")
                return
            start = float(start_time)
            if not math.isfinite(start):
                self._refuse(f"start time {start!r} is not allowed: must be a finite "
                             "number")
                return
            self.t0 = start
        except BaseException as exc:  # noqa: BLE001 - nothing may reach pythonfmu
            self._refuse(f"fmi2SetupExperiment failed: {type(exc).__name__}: {exc}")

    def enter_initialization_mode(self):
        """fmi2EnterInitializationMode: allowed once, right after instantiation."""
        if self.phase != "instantiated":
            self._refuse(f"fmi2EnterInitializationMode is not allowed in the {self.phase} "
                         "phase: only after fmi2Instantiate")
            return
        self.phase = "initialization"

    def exit_initialization_mode(self):
        """fmi2ExitInitializationMode: apply the Integer twins of the String parameters
        (item 9) and build the maths objects (``_setup``); a bad parameter or a version
        clash is logged and leaves the instance refusing to step (item 5)."""
        if self.phase != "initialization":
            self._refuse(f"fmi2ExitInitializationMode is not allowed in the {self.phase} "
                         "phase: only after fmi2EnterInitializationMode")
            return
        self.phase = "stepping"
        if self.instantiation_error is not None:
            self._refuse(self.instantiation_error)
            return
        self.error = None
        self.initialized = False
        try:
            self._resolve_choice_twins()
            self._quiet_setup()
            self.initialized = True
            self.t_next = self.t0
        except ParameterError as exc:
            self._refuse(str(exc))
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            self._refuse(f"initialization failed: {type(exc).__name__}: {exc}")

    def terminate(self):
        """fmi2Terminate: end the instance (a second call is refused)."""
        if self.phase == "terminated":
            self._refuse("fmi2Terminate is not allowed: the instance is already terminated")
            return
        self.phase = "terminated"

    def do_step(self, current_time: float, step_size: float) -> bool:
        """fmi2DoStep: one communication step from ``current_time`` (``_step``).

        Returns
        -------
        bool
            False (fmi2Discard, the reason logged) when the instance refuses the step
            (items 5 and 7) or the step fails, else True.
        """
        if self.error is not None:
            self.log(f"refusing to step: {self.error}", Fmi2Status.discard)
            return False
        reason = self._step_refusal(current_time, step_size)
        if reason is not None:
            self._refuse(reason)
            return False
        try:
            # The host's warning filters may turn numpy's overflow warnings into exceptions;
            # the slaves check their results for non-finite values themselves.
            if self.fp_guarded:
                self._step(current_time, step_size)
            else:
                with np.errstate(all="ignore"):
                    self._step(current_time, step_size)
        except ParameterError as exc:
            self._refuse(str(exc))
            return False
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            self._refuse(f"step at t = {current_time!r} failed: {type(exc).__name__}: {exc}")
            return False
        self.t_next = current_time + step_size
        return True

    def _step_refusal(self, t: float, h: float) -> str | None:
        """Why the FMI state machine forbids ``doStep(t, h)`` now (None: allowed)."""
        if self.phase != "stepping":
            return (f"fmi2DoStep is not allowed in the {self.phase} phase: only between "
                    "fmi2ExitInitializationMode and fmi2Terminate")
        if not self.initialized:
            return ("fmi2DoStep is not allowed: the instance is not initialized (a restored "
                    "FMU state was saved before initialization ended)")
        if not (math.isfinite(t) and math.isfinite(h) and h > 0):
            return (f"step size {h!r} at t = {t!r} is not allowed: must be a finite number "
                    "> 0 from a finite time")
        expected = self.t_next
        # libcosim keeps time in integer nanoseconds: its t differs from the sum of the
        # steps by about 1e-12 relative; a jump or a step back is many orders larger
        if expected is not None and abs(t - expected) > 1e-9 * max(abs(expected), h, 1.0):
            direction = "goes backwards" if t < expected else "jumps ahead"
            return (f"step from t = {t!r} is not allowed: time {direction}; the last step "
                    f"ended at {expected!r} (a step must start where the last one ended)")
        return None

    # -- value access: the FMI rules on what may be set when -----------------------------
    def _set_refusal(self, var) -> str | None:
        if self.phase == "terminated":
            return f"setting {var.name} is not allowed: the instance is terminated"
        causality = var.causality
        if causality not in (Fmi2Causality.parameter, Fmi2Causality.input) \
                or var.setter is None:
            return (f"setting {var.name} is not allowed: it is an {causality.name}, not a "
                    "parameter or an input")
        if causality == Fmi2Causality.parameter and self.phase == "stepping" and \
                var.variability != Fmi2Variability.tunable:
            return (f"setting {var.name} is not allowed after initialization: it is a "
                    f"{var.variability.name} parameter (set it before "
                    "fmi2ExitInitializationMode)")
        return None

    def _set(self, vrs, values, kind, convert) -> None:
        try:
            vrs, values = list(vrs), list(values)
            if len(vrs) != len(values):
                self._refuse(f"set{kind.__name__} with {len(vrs)} value references and "
                             f"{len(values)} values is not allowed")
                return
            for vr, value in zip(vrs, values):
                var = self.vars.get(vr)
                if var is None:
                    self._refuse(f"value reference {vr!r} is not allowed: this FMU has "
                                 f"0 .. {len(self.vars) - 1}")
                    return
                if not isinstance(var, kind):
                    self._refuse(f"set{kind.__name__} of {var.name} is not allowed: it is "
                                 f"a {type(var).__name__}")
                    return
                reason = self._set_refusal(var)
                if reason is not None:
                    self._refuse(reason)
                    return
                var.setter(convert(value))
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            self._refuse(f"set{kind.__name__} failed: {type(exc).__name__}: {exc}")

    def set_real(self, vrs, values):
        """fmi2SetReal: set the Real variables ``vrs`` to ``values`` (a refused set is logged,
        item 7)."""
        self._set(vrs, values, Real, float)

    def set_integer(self, vrs, values):
        """fmi2SetInteger: as ``set_real``, for Integer variables."""
        self._set(vrs, values, Integer, int)

    def set_boolean(self, vrs, values):
        """fmi2SetBoolean: as ``set_real``, for Boolean variables."""
        self._set(vrs, values, Boolean, bool)

    def set_string(self, vrs, values):
        """fmi2SetString: as ``set_real``, for String variables."""
        self._set(vrs, values, String, str)

    def _get(self, vrs, kind, convert, missing) -> list:
        out = []
        for vr in vrs:
            try:
                var = self.vars.get(vr)
                if var is None:
                    self._refuse(f"value reference {vr!r} is not allowed: this FMU has "
                                 f"0 .. {len(self.vars) - 1}")
                    out.append(missing)
                elif not isinstance(var, kind):
                    self._refuse(f"get{kind.__name__} of {var.name} is not allowed: it is "
                                 f"a {type(var).__name__}")
                    out.append(missing)
                else:
                    out.append(convert(var.getter()))
            except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
                self._refuse(f"get{kind.__name__} failed: {type(exc).__name__}: {exc}")
                out.append(missing)
        return out

    def get_real(self, vrs):
        """fmi2GetReal: the values of the Real variables ``vrs`` (NaN, with the error
        logged, for a value reference that is unknown or not a Real, or whose getter
        fails)."""
        return self._get(vrs, Real, float, math.nan)

    def get_integer(self, vrs):
        """fmi2GetInteger: as ``get_real``, for Integer variables (0 when refused)."""
        return self._get(vrs, Integer, int, 0)

    def get_boolean(self, vrs):
        """fmi2GetBoolean: as ``get_real``, for Boolean variables (False when refused)."""
        return self._get(vrs, Boolean, bool, False)

    def get_string(self, vrs):
        """fmi2GetString: as ``get_real``, for String variables (``""`` when refused)."""
        return self._get(vrs, String, str, "")

    def _setup(self) -> None:
        raise NotImplementedError

    def _quiet_setup(self) -> None:
        # numpy/scipy warnings may be errors in the host (its warning filters): the slaves
        # check their results for non-finite values instead
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self._setup()

    # -- FMU state -----------------------------------------------------------------------
    def _hidden_state(self) -> dict:
        """State of the maths objects that no FMI variable holds (JSON-friendly)."""
        return {}

    def _restore_hidden(self, hidden: dict) -> None:
        """Inverse of ``_hidden_state``, called after ``_setup`` rebuilt the maths."""

    def _state_data(self) -> dict:
        """The state as plain data (every settable variable, the times, the flags and the
        hidden state), a deep copy: later steps do not change it."""
        values = {v.name: v.getter() for v in self.vars.values() if v.setter is not None}
        state = {"model": type(self).__name__, "values": values, "t0": self.t0,
                 "t_next": self.t_next, "initialized": self.initialized, "error": self.error,
                 "hidden": self._hidden_state() if self.initialized else None}
        return json.loads(json.dumps(state, default=_plain))

    def _get_fmu_state(self) -> int:
        try:
            return StateHandle.new(self._state_data())
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            message = f"saving the FMU state failed: {type(exc).__name__}: {exc}"
            self.log(message, Fmi2Status.error)
            return StateHandle.new({"model": None, "invalid": message})

    def _set_fmu_state(self, handle) -> None:
        """fmi2SetFMUstate: the state checked field by field (``_check_state``, then
        ``_restore_hidden`` against the maths its parameters rebuild); a state that
        fails is refused (logged, the instance then refuses to step) and the instance's
        own state is put back."""
        try:
            if self.phase == "terminated":
                raise ParameterError("fmi2SetFMUstate is not allowed: the instance is "
                                     "terminated")
            state = StateHandle.data_of(handle)
            if "invalid" in state:
                raise ParameterError(state["invalid"])
            if state.get("model") != type(self).__name__:
                raise ParameterError(f"FMU state of model {state.get('model')!r} is not "
                                     f"allowed: this FMU is {type(self).__name__}")
            self._check_state(state)
            saved = self._state_data()
            try:
                self._apply_state(state)
            except BaseException:
                self._roll_back(saved)
                raise
        except ParameterError as exc:
            self._refuse(str(exc))
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            self._refuse(f"restoring the FMU state failed: {type(exc).__name__}: {exc}")

    def _check_state(self, state: dict) -> None:
        """The fields every slave's state has: each variable of this FMU with a value of
        its type, the times finite, the flags true or false, the error a message, the
        hidden state present exactly when the instance was initialized."""
        by_name = {v.name: v for v in self.vars.values() if v.setter is not None}
        values = state.get("values")
        if not isinstance(values, dict):
            raise state_refused("values", values, "an object of the variables' values")
        unknown = sorted(set(values) - set(by_name))
        if unknown:
            raise ParameterError(f"FMU state with variables {unknown} is not allowed: "
                                 "this FMU has no such variables (another build)")
        missing = sorted(set(by_name) - set(values))
        if missing:
            raise state_refused("values", sorted(values), f"every variable of this FMU "
                                f"(missing {missing})")
        for name, value in values.items():
            if not _value_ok(by_name[name], value):
                raise state_refused(name, value, _VALUE_TYPES[type(by_name[name])])
        state_number("t0", state.get("t0"))
        if state.get("t_next") is not None:
            state_number("t_next", state["t_next"])
        initialized = state_flag("initialized", state.get("initialized"))
        error = state.get("error")
        if not (error is None or isinstance(error, str)):
            raise state_refused("error", error, "null or a message")
        hidden = state.get("hidden")
        if initialized != isinstance(hidden, dict) or not (initialized or hidden is None):
            raise state_refused("hidden", hidden, "an object exactly when initialized = true"
                                f" (initialized = {initialized})")

    def _apply_state(self, state: dict) -> None:
        by_name = {v.name: v for v in self.vars.values()}
        for name, value in state["values"].items():
            by_name[name].setter(value)
        self.t0 = float(state["t0"])
        t_next = state.get("t_next")
        self.t_next = None if t_next is None else float(t_next)
        self.initialized = False
        self.error = None
        if state["initialized"]:
            try:
                self._quiet_setup()
            except ParameterError as exc:
                raise ParameterError(f"FMU state is not allowed: {exc} (initialized = true: "
                                     "its parameters must pass initialization's checks)"
                                     ) from None
            self._restore_hidden(state["hidden"])
            self.initialized = True
        self.error = state["error"]

    def _roll_back(self, saved: dict) -> None:
        """After a refused state: the instance's own state again (as far as it goes)."""
        try:
            self._apply_state(saved)
        except BaseException:  # noqa: BLE001 - the refusal is what the host sees
            pass

    @staticmethod
    def _fmu_state_to_bytes(handle) -> bytes:
        try:
            return json.dumps(StateHandle.data_of(handle), sort_keys=True).encode("utf-8")
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            return json.dumps({"model": None, "invalid": f"serializing the FMU state "
                               f"failed: {type(exc).__name__}: {exc}"}).encode("utf-8")

    @staticmethod
    def _fmu_state_from_bytes(data: bytes) -> int:
        try:
            state = json.loads(bytes(data).decode("utf-8"))
            if not isinstance(state, dict) or (not isinstance(state.get("values"), dict) \
                    and "invalid" not in state):
                raise ValueError("not a delaycomp FMU state")
        except BaseException as exc:  # noqa: BLE001 - never let it reach pythonfmu
            state = {"model": None, "invalid": f"FMU state of {len(data)} bytes is not "
                     f"allowed: it is not a state saved by a delaycomp FMU ({exc})"}
        return StateHandle.new(state)

    def _step(self, t: float, h: float) -> None:
        raise NotImplementedError

    # -- modelDescription --------------------------------------------------------------
    def to_xml(self, model_options=None):
        """The modelDescription (an ElementTree element) as pythonfmu writes it, with each
        output's dependencies declared and the outputs listed as InitialUnknowns (item 4)."""
        root = super().to_xml(model_options or {})
        index_of = {v.name: i + 1 for i, v in enumerate(self.vars.values())}
        outputs = root.find("ModelStructure/Outputs")
        if outputs is not None:
            for unknown in outputs.findall("Unknown"):
                var = list(self.vars.values())[int(unknown.get("index")) - 1]
                deps = self.dependencies.get(var.name, [])
                unknown.set("dependencies", " ".join(str(index_of[d]) for d in deps))
            # FMI 2.0, 2.2.8: outputs with initial="calculated" are initial unknowns.
            initial = SubElement(root.find("ModelStructure"), "InitialUnknowns")
            for unknown in outputs.findall("Unknown"):
                SubElement(initial, "Unknown", attrib={"index": unknown.get("index")})
        return root
