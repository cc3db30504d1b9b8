"""The user's model: one Python module describing a plant and its delay-free feedback.

A model module defines, at module level::

    STATES = ("x1", "x2")            # state names, in order
    INPUTS = ("u",)                  # input names, in order
    CONTROL = "zoh"                  # "continuous" (Theorem 2.1) or "zoh" (Theorem 3.2)
    PARAMETERS = {"a": 1.0}          # optional: numbers or strings the functions read
    CHOICES = {"law": ("a", "b")}    # optional: the allowed values of string parameters

    def f(x, u, p): ...              # dynamics x' = f(x, u), forward complete
    def k(t, x, p): ...              # CONTROL = "continuous": nominal feedback k(t, x)
    def k(x, p): ...                 # CONTROL = "zoh": nominal sampled-data feedback k(x)
    def predictor(x, segments, p): ...  # optional closed-form Phi
    def step(x, u, h, p): ...        # optional exact plant step under constant u
    BATCH = True                     # optional: f, k and step also take a batch of points

``x`` and ``u`` are 1-D numpy arrays, ``p`` a dict of the parameters (the controller adds
``T``, its sampling period). ``predictor`` receives the input history as segments
``(duration, u)`` covering ``[t - r - tau, t)`` oldest first and returns the state reached
from ``x`` after ``r + tau`` (Phi of the paper). Without it the controller solves the ODE.

``BATCH = True`` promises that ``f``, ``k`` and ``step`` also accept a batch of ``P``
points: ``x`` of shape ``(n, P)``, ``u`` of shape ``(m, P)``, ``h`` and ``t`` of shape
``(P,)``, and ``p["T"]`` of shape ``(P,)``; they return ``(n, P)`` and ``(m, P)`` arrays.
With it and an exact ``step``, sweeps run the model on the batch engine
(``delaycomp.studies.batch``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

from delaycomp.errors import DelaycompError

CONTROLS = ("continuous", "zoh")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class ModelError(DelaycompError, ValueError):
    """The model module does not follow the interface (one-line message)."""


@dataclass(frozen=True)
class Model:
    """A model file, loaded and checked: its names, ``CONTROL``, ``f``, ``k``, the optional exact
    ``predictor`` and ``step``, its parameters and String choices."""

    name: str
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    control: str
    f: Callable
    k: Callable
    parameters: dict = field(default_factory=dict)
    predictor: Callable | None = None
    step: Callable | None = None
    source: Path | None = None
    #: allowed values of string parameters (optional ``CHOICES`` of the module)
    choices: dict = field(default_factory=dict)
    #: ``f``, ``k`` and ``step`` accept a batch of points (optional ``BATCH`` of the module)
    batch: bool = False

    @property
    def n(self) -> int:
        """The number of states."""
        return len(self.states)

    @property
    def m(self) -> int:
        """The number of inputs."""
        return len(self.inputs)

    def params(self, **overrides) -> dict:
        """The model's parameters with ``overrides`` (a new dict)."""
        p = dict(self.parameters)
        p.update(overrides)
        return p


def from_module(module: ModuleType, name: str | None = None) -> Model:
    """Check a model module against the interface and wrap it."""
    label = name or module.__name__

    def need(attr):
        if not hasattr(module, attr):
            raise ModelError(f"model {label}: missing {attr}")
        return getattr(module, attr)

    states = tuple(need("STATES"))
    inputs = tuple(need("INPUTS"))
    for kind, names in (("STATES", states), ("INPUTS", inputs)):
        if not names:
            raise ModelError(f"model {label}: {kind} is empty")
        bad = [s for s in names if not isinstance(s, str) or not _NAME.match(s)]
        if bad:
            raise ModelError(f"model {label}: {kind} has names that are not identifiers: {bad}")
    if len(set(states + inputs)) != len(states) + len(inputs):
        raise ModelError(f"model {label}: state and input names must be distinct")
    control = need("CONTROL")
    if control not in CONTROLS:
        raise ModelError(f"model {label}: CONTROL = {control!r}, must be one of {CONTROLS}")
    params = dict(getattr(module, "PARAMETERS", {}))
    for key, value in params.items():
        if not _NAME.match(str(key)) or not isinstance(value, (int, float, str)):
            raise ModelError(f"model {label}: PARAMETERS[{key!r}] must be a number or a string")
    choices = {key: tuple(values) for key, values in getattr(module, "CHOICES", {}).items()}
    for key, values in choices.items():
        if key not in params or params[key] not in values:
            raise ModelError(f"model {label}: CHOICES[{key!r}] must list the values of a "
                             "string parameter, its default among them")
    batch = getattr(module, "BATCH", False)
    if not isinstance(batch, bool):
        raise ModelError(f"model {label}: BATCH = {batch!r}, must be True or False")
    f, k = need("f"), need("k")
    arity = len(inspect.signature(k).parameters)
    if arity != (3 if control == "continuous" else 2):
        form = "k(t, x, p)" if control == "continuous" else "k(x, p)"
        raise ModelError(f"model {label}: CONTROL = {control!r} needs {form}")
    _check_shapes(label, f, k, control, len(states), len(inputs), params)
    file = getattr(module, "__file__", None)
    return Model(label, states, inputs, control, f, k, params,
                 getattr(module, "predictor", None), getattr(module, "step", None),
                 Path(file) if file else None, choices, batch)


def _check_shapes(label, f, k, control, n, m, params) -> None:
    """``f`` must return ``n`` entries and ``k`` ``m``: checked once, at ``x = 0``,
    ``u = 0``, ``t = 0`` and the default parameters (with ``T = 1``). A function that
    raises there is not judged here (a model may be undefined at 0): its own exception is
    reported where a run calls it."""
    import numpy as np

    p = {**params, "T": 1.0}
    x, u = np.zeros(n), np.zeros(m)
    for what, call, want in (
            ("f(x, u, p)", lambda: f(x, u, p), n),
            ("k(t, x, p)" if control == "continuous" else "k(x, p)",
             (lambda: k(0.0, x, p)) if control == "continuous" else (lambda: k(x, p)), m)):
        try:
            with np.errstate(all="ignore"):
                shape = np.shape(call())
        except BaseException:  # noqa: BLE001 - see the docstring (SystemExit included)
            continue
        if shape != (want,):
            raise ModelError(f"model {label}: {what} returned shape {shape}, must be "
                             f"({want},): one entry per "
                             f"{'state' if want == n and what.startswith('f') else 'input'}")


def model_id(model_path: str | Path) -> str:
    """Identifier of a model file: its name and a digest of its content and our version."""
    from delaycomp.version import __version__

    path = Path(model_path)
    digest = hashlib.sha256(path.read_bytes() + __version__.encode()).hexdigest()
    return f"{_slug(path.stem)}_{digest[:8]}"


def module_name(model_path: str | Path) -> str:
    """The name a model file is imported under, here and inside its FMUs
    (``delaycomp_model_<model id>``): one import per process, whoever asks first."""
    return f"delaycomp_model_{model_id(model_path)}"


def load_model(path: str | Path) -> Model:
    """Import a model file (once per process: under ``module_name``, the name its FMUs
    import it by) and check it."""
    path = Path(path)
    if not path.is_file() or path.suffix != ".py":
        raise ModelError(f"--model {path}: not a Python file")
    mod_name = module_name(path)
    module = sys.modules.get(mod_name)
    if module is None:
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:  # a .py file always has one
            raise ModelError(f"--model {path}: not importable as a Python module")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException as exc:  # noqa: BLE001 - the user's code: one line
            del sys.modules[mod_name]
            raise ModelError(f"--model {path}: importing it failed: {type(exc).__name__}: "
                             f"{exc}") from None
    return from_module(module, path.stem)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", text)
