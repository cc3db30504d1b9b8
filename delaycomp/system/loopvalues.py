"""A loop file's values, checked one by one: the parser of a ``--set`` value, the check of
each key's value on its own (``KEYS``, ``check_value``), the sign guard of an LTI gain
(``check_sign``), a table's keys and a model's own parameters.

The rules between keys (the base grid, the zero-order hold, the loop's shape) are the
reader's, ``delaycomp.system.loopfile``; the keys, their ranges in words and their defaults
are ``delaycomp.system.loopkeys``.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as the tomli package
    import tomli as tomllib

from delaycomp.errors import ParameterError
from delaycomp.names import MODES
from delaycomp.system.loopkeys import ALLOWED, PREDICTORS

#: an ASCII decimal number (a ``--set`` value, a trace file's delay)
DECIMAL = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$", re.ASCII)


class SignError(ParameterError):
    """An LTI gain with which the delay-free sampled loop is unstable (the sign guard)."""


# -- values ---------------------------------------------------------------------------------

#: why a value or file nested beyond what the parser can read is refused
NESTED = ("its arrays or tables are nested too deeply to read (a loop needs at most a "
          "matrix: two levels)")


def parse_value(text: str) -> Any:
    """A ``--set`` value: an ASCII decimal number, ``a,b,c`` (a list), ``a,b;c,d`` (rows),
    a TOML array ``[[a, b], [c, d]]``, a TOML inline table ``{name = value}``,
    ``true``/``false``, or else the text itself.

    Examples
    --------
    >>> parse_value("0.4"), parse_value("1,0"), parse_value("1,2;3,4")
    (0.4, [1.0, 0.0], [[1.0, 2.0], [3.0, 4.0]])
    >>> parse_value("[[1, 2]]"), parse_value("uncompensated"), parse_value("true")
    ([[1, 2]], 'uncompensated', True)
    """
    text = text.strip()
    if DECIMAL.match(text):
        return float(text)
    if text in ("true", "false"):
        return text == "true"
    if text.startswith("{"):  # a TOML inline table: plant.parameters={mass = 2.0}
        try:
            return tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"not a TOML inline table: {exc}") from None
        except RecursionError:
            raise ValueError(NESTED) from None
    if text.startswith("["):
        if "_" in text:
            raise ValueError("plain decimal numbers only (no '_')")
        try:
            return tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"not a TOML array: {exc}") from None
        except RecursionError:
            raise ValueError(NESTED) from None
    if "," in text or ";" in text:
        rows = [[_number(part) for part in row.split(",")] for row in text.split(";")]
        return rows if ";" in text else rows[0]
    return text


def _number(text: str) -> float:
    text = text.strip()
    if not DECIMAL.match(text):
        raise ValueError(f"{text!r} is not an ASCII decimal number")
    return float(text)


def real_value(where: str, value, positive=False, nonneg=False) -> float:
    """``value`` as a finite float (``> 0`` with ``positive``, ``>= 0`` with ``nonneg``);
    ``ParameterError`` naming ``where`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be a number")
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be a finite number")
    if positive and not value > 0:
        raise ParameterError(f"{where} = {value!r} is not allowed: must be > 0")
    if nonneg and not value >= 0:
        raise ParameterError(f"{where} = {value!r} is not allowed: must be >= 0")
    return value


def _int(where: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (
            isinstance(value, float) and not value.is_integer()) or not value >= 1:
        raise ParameterError(f"{where} = {value!r} is not allowed: must be a positive integer")
    return int(value)


def array_value(where: str, value, ndim: int) -> np.ndarray:
    """``value`` as a non-empty array of ``ndim`` (1: a list, 2: rows) finite floats;
    ``ParameterError`` naming ``where`` otherwise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{where} is not allowed: must be "
                             f"{'a list of numbers' if ndim == 1 else 'a list of rows'}"
                             ) from None
    if ndim == 2 and arr.ndim == 1:
        arr = arr.reshape(1, -1) if arr.size else arr.reshape(0, 0)
    if arr.ndim != ndim or arr.size == 0 or _has_bool(value):
        raise ParameterError(f"{where} is not allowed: must be "
                             f"{'a list of numbers' if ndim == 1 else 'a list of rows of numbers'}")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{where} is not allowed: every entry must be a finite number")
    return arr


def _has_bool(value) -> bool:
    """Whether a (nested) list holds a TOML boolean, which numpy would take for 0 or 1."""
    if isinstance(value, (list, tuple)):
        return any(_has_bool(v) for v in value)
    return isinstance(value, bool)


def flag_value(where: str, value) -> bool:
    """``value``, a TOML boolean; ``ParameterError`` naming ``where`` otherwise."""
    if not isinstance(value, bool):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be true or false")
    return value


def _mode(where: str, value) -> str:
    if value not in MODES:
        raise ParameterError(f"{where} = {value!r} is not allowed: must be "
                             f"{' or '.join(MODES)}")
    return value


def _predictor(where: str, value) -> str:
    if value not in PREDICTORS:
        raise ParameterError(f"{where} = {value!r} is not allowed: must be "
                             f"{' or '.join(PREDICTORS)}")
    return value


@dataclass(frozen=True)
class Key:
    """A loop-file key whose value is checked on its own: ``check(where, value)`` returns
    the value checked (or raises ``ParameterError`` naming ``where``); ``allowed`` says
    the range in words (the rules between keys, such as the base grid, are ``check``'s)."""

    check: Callable[[str, Any], Any]
    allowed: str


def _nonneg(where: str, value) -> float:
    return real_value(where, value, nonneg=True)


def _positive(where: str, value) -> float:
    return real_value(where, value, positive=True)


def _vector(where: str, value) -> np.ndarray:
    return array_value(where, value, 1)


def _matrix(where: str, value) -> np.ndarray:
    return array_value(where, value, 2)


#: the keys checked on their own, each rule written once (what ``check_value`` and the
#: reader apply), each with its allowed values in words (``.loopkeys.ALLOWED``); a model's
#: own parameters are checked against the model (``check``)
_CHECKS: dict[str, Callable[[str, Any], Any]] = {
    "T": _positive,
    "N": _int,
    **dict.fromkeys(("r", "tau", "r_true", "tau_true"), _nonneg),
    "stop_time": _positive,
    "plant.A": _matrix,
    "plant.B": _matrix,
    "plant.x0": _vector,
    "controller.K": _matrix,
    "controller.u0": _vector,
    "controller.mode": _mode,
    "controller.predictor": _predictor,
    "controller.pad": flag_value,
    "controller.allow_unstable": flag_value,
    "controller.stamps": flag_value,
    "controller.age_max": _nonneg,
}
KEYS: dict[str, Key] = {key: Key(check, ALLOWED[key]) for key, check in _CHECKS.items()}
assert KEYS.keys() == ALLOWED.keys()  # every key checked, and said in words


def check_value(key: str, value, where: str | None = None) -> Any:
    """``value`` of loop-file ``key`` (``"T"``, ``"plant.x0"``, ``"controller.mode"``)
    checked on its own, as the reader checks it; a key not in ``KEYS`` passes as it is.

    Examples
    --------
    >>> check_value("N", 20.0), check_value("controller.mode", "uncompensated")
    (20, 'uncompensated')
    >>> check_value("T", 0)
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: T = 0.0 is not allowed: must be > 0
    """
    spec = KEYS.get(key)
    return value if spec is None else spec.check(where or key, value)


# -- the sign guard ------------------------------------------------------------------------

def check_sign(A, B, K, T: float) -> float:
    """Refuse (``SignError``) a gain with which the delay-free sampled loop
    ``x_{i+1} = (Ad + Bd K) x_i`` is unstable; return its spectral radius otherwise.

    Examples
    --------
    >>> round(check_sign([[1.0]], [[1.0]], [[-2.0]], 1.0), 6)    # Example 3.6: stable
    0.718282
    >>> check_sign([[1.0]], [[1.0]], [[2.0]], 1.0)   # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.system.loopvalues.SignError: controller K: the delay-free sampled loop ...
    """
    A, B, K = (np.atleast_2d(np.asarray(M, dtype=float)) for M in (A, B, K))
    rho = _radius(A.shape, A.tobytes(), B.shape, B.tobytes(), K.shape, K.tobytes(), T)
    if math.isnan(rho):  # e^(A T) overflowed: there is no sampled loop to judge
        raise SignError(
            f"plant A = {A.tolist()} with T = {T!r} is not allowed: the sampled plant "
            "e^(A T) overflows (it is not finite), so the delay-free sampled loop cannot be "
            "judged; set allow_unstable = true (--allow-unstable) to run it anyway")
    if not rho < 1.0:
        raise SignError(
            f"controller K: the delay-free sampled loop is unstable (spectral radius of "
            f"Ad + Bd K = {rho:.6g} >= 1 at T = {T!r}); delaycomp applies u = K x, whereas "
            "python-control's lqr/dlqr return K for u = -K x (pass -K); set "
            "allow_unstable = true (--allow-unstable) to study an unstable design")
    return rho


@functools.lru_cache(maxsize=256)
def _radius(sa, a, sb, b, sk, k, T: float) -> float:
    """``sampled_radius`` by value, remembered: a sweep's grid points
    share their matrices and repeat the guard."""
    from delaycomp.maths.lti import sampled_radius

    def mat(shape, data):
        return np.frombuffer(data, dtype=float).reshape(shape)

    return sampled_radius(mat(sa, a), mat(sb, b), mat(sk, k), T)


# -- a table's keys, a model's own parameters -----------------------------------------------

def check_keys(where: str, table: dict, allowed, extra=()) -> None:
    """Refuse a key of ``table`` neither in ``allowed`` nor in ``extra``, naming ``where``."""
    for key in table:
        if key not in allowed and key not in extra:
            raise ParameterError(f"{where}: unknown key {key!r}: allowed are "
                                 f"{', '.join(allowed)}")


def model_value(model, key: str, value, where: str | None = None) -> Any:
    """``value`` of a model's own parameter ``key`` (``[controller] law = "printed"``)
    checked against the model (``delaycomp.maths.model``): a string among its choices,
    or a finite number."""
    where = where or f"controller.{key}"
    if isinstance(model.parameters[key], str):
        if not isinstance(value, str):
            raise ParameterError(f"{where} = {value!r} is not allowed: must be a string")
        choices = model.choices.get(key)
        if choices and value not in choices:
            raise ParameterError(f"{where} = {value!r} is not allowed: must be one of "
                                 f"{', '.join(choices)}")
        return value
    return real_value(where, value)
