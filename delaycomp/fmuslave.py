"""Thin base class shared by the project's pythonfmu slaves.

It does the FMI bookkeeping that every slave of this project needs, so that each slave
module only declares its variable table and calls the maths:

1. the build configuration (dimensions, names) is read from ``delaycomp_fmu.json`` in the
   FMU's resources, written there by :mod:`delaycomp.build`;
2. the bundled package version is checked against the one the FMU was built with
   (pythonfmu slaves share the host's ``sys.modules``: a different ``delaycomp`` already
   imported in the host would silently run other code);
3. the GUID is pinned (a UUID5 of model name, version and configuration), so that a rebuild
   of the same sources gives the same modelDescription;
4. the ModelStructure lists each output's dependencies on inputs (direct feedthrough),
   which pythonfmu leaves undeclared;
5. no Python exception leaves the slave for an expected fault. pythonfmu 0.7 turns every
   exception into fmi2Fatal and drops the Python object (a later fmi2Terminate crashes the
   host, and repeated fatal errors have crashed the interpreter). Instead a bad parameter
   is logged with status error when initialization ends, and every later ``doStep``
   returns fmi2Discard with the reason logged; a fault during a step does the same.

Subclasses implement ``_setup()`` (check parameters, build the maths objects) and
``_step(t, h)`` (the maths of one communication step).
"""

from __future__ import annotations

import json
import math
import os
import sys
import uuid
from collections.abc import Callable, Iterable
from xml.etree.ElementTree import SubElement

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real, String
from pythonfmu.enums import Fmi2Initial, Fmi2Status

import delaycomp

CONFIG_NAME = "delaycomp_fmu.json"
#: pythonfmu 0.7's runtime releases one reference to the slave module's ``__dict__`` each
#: time it instantiates the slave class (measured: a module whose dict nothing else holds
#: is freed after the first instance, and the next instantiation reads freed memory). Each
#: instance therefore pins one reference; generated slave modules also pin one at import.
_PINNED_MODULE_DICTS: list = []
#: When a controller reads its measurement: ``instant`` (the value set at the sampling
#: instant t_i: direct feedthrough, for a master that sets inputs before reading outputs) or
#: ``previous-step`` (the value held over the base step [t_i - h, t_i): no feedthrough, what a
#: Jacobi master delivers; the measurement delay is then shortened by h to compensate).
SAMPLINGS = ("instant", "previous-step")
SAMPLING_HELP = ("instant (y set at t_i) or previous-step (y held over [t_i - h, t_i), for "
                 "Jacobi masters)")
_GUID_NAMESPACE = uuid.UUID("6f1c9a4e-3d52-4b7a-9e0f-d3e1a2c4b5f6")


class ParameterError(ValueError):
    """A parameter value outside its allowed range; the message names both."""


def check_finite(name: str, value: float) -> float:
    if not math.isfinite(value):
        raise ParameterError(f"{name} = {value!r} is not allowed: must be a finite number")
    return value


class TableSlave(Fmi2Slave):
    """Base of the project's slaves: configuration, pinned GUID, declared dependencies."""

    description = "delaycomp FMU"
    author = "delaycomp contributors"
    license = "MIT"
    version = delaycomp.__version__

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        _PINNED_MODULE_DICTS.append(vars(sys.modules[type(self).__module__]))
        self.config = self._read_config()
        built_with = self.config.get("version")
        if built_with != delaycomp.__version__:
            raise RuntimeError(
                f"{type(self).__name__}: built with delaycomp {built_with}, but delaycomp "
                f"{delaycomp.__version__} is already loaded in this process"
            )
        key = json.dumps({"model": type(self).__name__, "config": self.config}, sort_keys=True)
        self.guid = uuid.uuid5(_GUID_NAMESPACE, key)
        #: output name -> names of the inputs it depends on at the same instant
        self.dependencies: dict[str, list[str]] = {}
        #: why this instance refuses to step (None while it is healthy)
        self.error: str | None = None

    def _read_config(self) -> dict:
        if self.resources is None:
            raise RuntimeError(f"{type(self).__name__}: no resources folder")
        with open(os.path.join(self.resources, CONFIG_NAME), encoding="utf-8") as fh:
            return json.load(fh)

    # -- registration helpers ----------------------------------------------------------
    def parameter(
        self, name: str, getter: Callable[[], float], setter: Callable[[float], None],
        description: str,
    ) -> None:
        self.register_variable(
            Real(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                 getter=getter, setter=setter, description=description)
        )

    def string_parameter(
        self, name: str, getter: Callable[[], str], setter: Callable[[str], None],
        description: str,
    ) -> None:
        self.register_variable(
            String(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                   getter=getter, setter=setter, description=description)
        )

    def model_parameters(self, values: dict, defaults: dict) -> None:
        """One FMU parameter per model parameter (Real for numbers, String for strings),
        stored in ``values``."""
        for name, default in defaults.items():
            values[name] = default if isinstance(default, str) else float(default)
            register = self.string_parameter if isinstance(default, str) else self.parameter
            register(name, (lambda n=name: values[n]),
                     (lambda v, n=name: values.__setitem__(n, v)), "model parameter")

    def real_input(self, name: str, getter, setter, description: str) -> None:
        self.register_variable(
            Real(name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                 getter=getter, setter=setter, description=description)
        )

    def real_output(
        self, name: str, getter, description: str, depends_on: Iterable[str] = (),
        variability: Fmi2Variability = Fmi2Variability.continuous,
    ) -> None:
        self.register_variable(
            Real(name, causality=Fmi2Causality.output, variability=variability,
                 initial=Fmi2Initial.calculated, getter=getter, description=description)
        )
        self.dependencies[name] = list(depends_on)

    def fail(self, message: str) -> None:
        """Abandon ``_setup`` or ``_step`` with ``message`` (logged by the caller)."""
        raise ParameterError(message)

    def _refuse(self, message: str) -> None:
        self.error = message
        self.log(message, Fmi2Status.error)

    # -- FMI entry points ----------------------------------------------------------------
    def exit_initialization_mode(self):
        self.error = None
        try:
            self._setup()
        except ParameterError as exc:
            self._refuse(str(exc))
        except Exception as exc:  # noqa: BLE001 - never let it reach pythonfmu
            self._refuse(f"initialization failed: {type(exc).__name__}: {exc}")

    def do_step(self, current_time: float, step_size: float) -> bool:
        if self.error is not None:
            self.log(f"refusing to step: {self.error}", Fmi2Status.discard)
            return False
        try:
            self._step(current_time, step_size)
        except ParameterError as exc:
            self._refuse(str(exc))
            return False
        except Exception as exc:  # noqa: BLE001 - never let it reach pythonfmu
            self._refuse(f"step at t = {current_time!r} failed: {type(exc).__name__}: {exc}")
            return False
        return True

    def _setup(self) -> None:
        raise NotImplementedError

    def _step(self, t: float, h: float) -> None:
        raise NotImplementedError

    # -- modelDescription --------------------------------------------------------------
    def to_xml(self, model_options=None):
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
