"""Loop files: a closed loop described in TOML, the user's own system for every command.

The shape is a contract (scripts and checks write such files; it is extended, never
renamed)::

    T = 0.2                 # sampling period [s], > 0
    N = 20                  # base steps per period (h = T/N); default 100
    r = 0.36                # measurement delay [s], a multiple of h; default 0
    tau = 0.4               # input delay [s], a multiple of T (zero-order hold); default 0
    # r_true, tau_true      optional: the loop's real delays when they differ
    stop_time = 10.0        # optional: the default stop time of `run` [s]

    [plant]
    A = [[0, 1, 0], [0, 0, 1], [-1, -2, -3]]     # LTI: x' = A x + B u (any n, m) ...
    B = [[0, 0], [1, 0], [0, 1]]
    # model = "pend.py"                         # ... or a model file (delaycomp.maths.model)
    x0 = [1, 0, 0]          # the constant history of x on [-r, 0]

    [controller]
    mode = "compensated"    # or "uncompensated" (the sample itself instead of Phi)
    K = [[-1, -2, 0], [0, -1, -1]]  # LTI: u = K x, the paper's sign (not python-control's)
    u0 = [0, 0]             # the constant input history on [-r - tau, 0); default zeros
    # gain = 2.0            # a model's own parameters, by name

Extensions (optional keys): top-level ``name`` and ``title``; ``[plant] state`` and
``input`` (base names of the LTI signals, default ``x`` and ``u``), ``[plant] tolerance``
(a model plant without exact ``step``: its ODE tolerance; a plant FMU: the relative
tolerance of its ``fmi2SetupExperiment``, in (0, 1)); ``[controller] predictor``
(``closed`` or ``numerical``, for models), ``pad`` (the LTI controller, a plant FMU's
included, and a zero-order-hold model's: pad ``tau`` up to a multiple of T, Remark
3.3(b)), ``tolerance`` and ``allow_unstable``.

A plant FMU from another tool (``.plantfmu``): ``[plant] fmu``, ``states`` (its
outputs measured), ``inputs``, ``x0`` (the measured history: the FMU must start there),
``parameters`` and ``start`` (tables of values set before its initialization); the
predictor from ``[controller]`` ``A``, ``B`` and ``K``, ``model``, or ``predictor =
"plant-fmu"`` with ``K`` (the FMU's own Model Exchange derivatives, ``.fmumodel``).

A network channel in a delay's place: a ``[meas_delay]`` or ``[input_delay]``
table with the keys of ``delaycomp.maths.channel.Channel`` (``distribution``, ``jitter``,
``loss_model``, ``seed``, a ``trace`` CSV file, ...; ``with_channels``).

Relative paths resolve against the loop file's folder. ``--set NAME=VALUE`` overrides take
the file's keys: ``r=0.4``, ``plant.x0=1,0,0``, ``controller.K=-1,-2,0;0,-1,-1`` (rows by
``;``) or ``controller.K=[[-1,-2,0],[0,-1,-1]]``, ``controller.mode=uncompensated``; and
one value of a plant FMU's ``parameters`` or ``start`` table: ``plant.parameters.NAME=VALUE``,
where all after ``parameters.`` is the FMU's variable name (``plant.parameters.fixed.phi0=0``,
or quoted as a TOML key: ``plant.parameters."fixed.phi0"=0``; ``plant.start.body.phi=0.4``).

**The sign, guarded.** For an LTI loop, a ``K`` with which the delay-free sampled loop is
unstable (spectral radius of ``Ad + Bd K`` at least 1) is refused: the controller applies
``u = K x`` whereas python-control's ``lqr``/``dlqr`` return ``K`` for ``u = -K x``.
``allow_unstable = true`` lets a study of unstable designs through.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as the tomli package
    import tomli as tomllib

from delaycomp.errors import BadFileError, ParameterError, shown
from delaycomp.maths.grid import on_grid
from delaycomp.names import MODES
from delaycomp.system.loop import (
    Instance,
    Loop,
    LtiBatch,
    LtiPoint,
    Origin,
    check_model_loop,
    check_zoh_delay,
    design_loop,
    lti_design,
    lti_designs,
    model_loop,
)
from delaycomp.system.loopkeys import ALLOWED, CHANNEL_TABLES, DEFAULTS, PREDICTORS, allowed
from delaycomp.system.loopkeys import ON_BASE_GRID as ON_BASE_GRID  # importable here as before
from delaycomp.system.loopkeys import ZOH_TAU as ZOH_TAU
from delaycomp.system.loopkeys import ZOH_TAU_PAD as ZOH_TAU_PAD

#: the keys of each table, required or not, and the defaults: ``.loopkeys``
TOP_KEYS = allowed("", "lti")
SECTIONS = ("plant", "controller")
#: tables that describe something besides the loop (``[reference]``: for ``check``)
OTHER_TABLES = ("reference",)
DEFAULT_N: int = int(DEFAULTS["N"])  # type: ignore[call-overload]

_DECIMAL = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$", re.ASCII)


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
    if _DECIMAL.match(text):
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
    if not _DECIMAL.match(text):
        raise ValueError(f"{text!r} is not an ASCII decimal number")
    return float(text)


def _real(where: str, value, positive=False, nonneg=False) -> float:
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


def _array(where: str, value, ndim: int) -> np.ndarray:
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


def _flag(where: str, value) -> bool:
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
    return _real(where, value, nonneg=True)


def _positive(where: str, value) -> float:
    return _real(where, value, positive=True)


def _vector(where: str, value) -> np.ndarray:
    return _array(where, value, 1)


def _matrix(where: str, value) -> np.ndarray:
    return _array(where, value, 2)


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
    "controller.pad": _flag,
    "controller.allow_unstable": _flag,
    "controller.stamps": _flag,
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
    delaycomp.system.loopfile.SignError: controller K: the delay-free sampled loop ...
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


# -- the file ------------------------------------------------------------------------------

def _check_keys(where: str, table: dict, allowed, extra=()) -> None:
    for key in table:
        if key not in allowed and key not in extra:
            raise ParameterError(f"{where}: unknown key {key!r}: allowed are "
                                 f"{', '.join(allowed)}")


class LoopFile:
    """A loop file read from disk: ``loop`` builds the ``Loop``, with overrides.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (folder / "ex.toml").write_text('''
    ... T = 1.0
    ... r = 0.3
    ... tau = 1.0
    ... [plant]
    ... A = [[1.0]]
    ... B = [[1.0]]
    ... x0 = [1.0]
    ... [controller]
    ... K = [[-2.0]]
    ... ''')
    >>> lf = LoopFile(folder / "ex.toml")
    >>> loop = lf.loop(["r=0.5", "controller.mode=uncompensated"])
    >>> loop.name, loop.by_role("controller").parameters["mode"], loop.lti.r
    ('ex', 'uncompensated', 0.5)
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise BadFileError(self.path, "no such loop file")
        try:
            self.data = tomllib.loads(self.path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise BadFileError(self.path, f"is not a TOML loop file: {exc}") from None
        except RecursionError:
            raise BadFileError(self.path, f"is not allowed: {NESTED}") from None
        except OSError as exc:
            raise BadFileError(self.path, f"cannot be read: {exc.strerror}") from None
        self.name = str(self.data.get("name") or self.path.stem)
        self.title = str(self.data.get("title") or f"loop file {self.path.name}")

    @property
    def base(self) -> Path:
        """The folder relative paths resolve against."""
        return self.path.resolve().parent

    @property
    def where(self) -> str:
        """How a message names it: the file's name."""
        return self.path.name

    @property
    def default_stop_time(self) -> float | None:
        """The file's ``stop_time`` (checked), or ``None`` where it gives none."""
        stop = self.data.get("stop_time")
        return None if stop is None else _real("stop_time", stop, positive=True)

    def resolve(self, assignments: list[str] | dict | None = None) -> dict:
        """The file's data with ``NAME=VALUE`` overrides (``r``, ``plant.x0``,
        ``controller.K``); the keys are checked, the values when the loop is built."""
        # overrides replace top-level keys and keys of a section, nothing deeper (and the
        # loop is built without changing its data): a copy two levels deep suffices
        data = {k: dict(v) if isinstance(v, dict) else v for k, v in self.data.items()}
        items = assignments.items() if isinstance(assignments, dict) else (
            _split(a) for a in (assignments or []))
        for key, text in items:
            key = long_key(key, data)
            section, dot, name = key.partition(".")
            if not dot:
                section, name = "", key
            try:
                value = parse_value(text) if isinstance(text, str) else text
            except ValueError as exc:
                raise ParameterError(f"--set {key}={shown(text)}: {exc}") from None
            value = _listed(key, value)
            if section == "":
                _check_keys(self.where, {name: 0}, TOP_KEYS)
                data[name] = value
            elif section in SECTIONS or section in CHANNEL_TABLES:
                table = data.setdefault(section, {})
                if not isinstance(table, dict):
                    raise ParameterError(f"--set {key}: {section} in {self.where} is "
                                         "not a table")
                sub, dot, var = name.partition(".")
                if section == "plant" and sub in ("parameters", "start") and dot:
                    # plant.parameters.NAME, plant.start.NAME: all after the first dot is
                    # the FMU's own variable name (dotted, or quoted as in TOML)
                    params = table.get(sub) or {}
                    if not isinstance(params, dict):
                        raise ParameterError(f"--set {key}: plant.{sub} in "
                                             f"{self.where} is not a table")
                    table[sub] = {**params, _fmu_name(key, var, sub): value}
                    continue
                table[name] = value
            else:
                raise ParameterError(f"--set {key}: unknown section {section!r}: allowed "
                                     f"are {', '.join((*SECTIONS, *CHANNEL_TABLES))} (or a "
                                     "top-level key: "
                                     f"{', '.join(TOP_KEYS)})")
        return data

    def make(self, data: dict) -> Loop:
        """The loop of resolved ``data``."""
        return build(data, self.base, self.name, self.title, where=self.where)

    def design(self, data: dict) -> LtiPoint | None:
        """The design and timing of resolved ``data`` without the loop's instances (for an
        LTI loop file; ``None`` otherwise): see ``design``."""
        return design(data, where=self.where)

    def designs(self, datas: list[dict]) -> LtiBatch | None:
        """The designs of many resolved points at once, or ``None``: see ``designs``."""
        return designs(datas, where=self.where)

    def loop(self, assignments: list[str] | dict | None = None) -> Loop:
        """The loop for ``NAME=VALUE`` assignments over the file's values."""
        return self.make(self.resolve(assignments))


class LoopData(LoopFile):
    """A loop file held in memory: the loop-file data a ``Loop`` was built from
    (``Loop.origin``), read as a file is (``resolve`` with overrides, ``make``,
    ``loop``, a sweep's grid). Messages name it ``loop 'NAME'``.

    Examples
    --------
    >>> loop = LoopData({"T": 1.0, "r": 0.5, "plant": {"A": [[1.0]], "B": [[1.0]],
    ...                  "x0": [1.0]}, "controller": {"K": [[-2.0]]}}, name="ex").loop()
    >>> loop.origin is not None
    True
    >>> again = LoopData.of(loop).loop(["r=0.25", "K=-1.5"])
    >>> again, again.lti.r, again.lti.K.tolist()
    (<Loop 'ex' n=1 m=1 T=1 N=100>, 0.25, [[-1.5]])
    """

    def __init__(self, data, base: Path | None = None, name: str = "loop", title: str = "",
                 stop_time: float | None = None):
        self.data = dict(data)
        self._base = base
        self.name = name
        self.title = title
        self._stop = stop_time

    @classmethod
    def of(cls, loop: Loop) -> LoopData:
        """The loop-file data of ``loop`` (its ``origin``), checked to build
        ``loop`` itself: a loop built otherwise, or changed since (``Loop.replace``,
        ``set_parameters``), is refused (a ``ParameterError`` naming it)."""
        if loop.origin is None:
            raise ParameterError(
                f"source = {loop!r} is not allowed here: it keeps no loop-file data to build "
                "it again with other values (build it with load, lti or model, or give its "
                "loop file)")
        src = cls(loop.origin.data, loop.origin.base, loop.name, loop.title, loop.stop_time)
        if src.loop() != loop:
            raise ParameterError(
                f"source = {loop!r} is not allowed here: it was changed after it was built "
                "(Loop.replace, set_parameters) and its loop-file data no longer builds it; "
                "give the changes as overrides (sets) instead")
        return src

    @property
    def base(self) -> Path:
        """The folder relative paths resolve against (the working directory if none)."""
        return self._base if self._base is not None else Path.cwd()

    @property
    def where(self) -> str:
        """How a message names it: ``loop 'NAME'``."""
        return f"loop {self.name!r}"

    @property
    def default_stop_time(self) -> float | None:
        """The loop's stop time, else the data's (``None`` where neither has one)."""
        return self._stop if self._stop is not None else super().default_stop_time

    def make(self, data: dict) -> Loop:
        """The loop of resolved ``data``, with the loop's stop time where the data give
        none and it lies on the base grid."""
        loop = super().make(data)
        if data.get("stop_time") is None and self._stop is not None and on_grid(
                self._stop, loop.h):
            loop = loop.replace(stop_time=self._stop)
        return loop


#: the short names of loop-file keys that ``--set``, ``sets``, overrides and grids may use:
#: ``x0`` for ``plant.x0``, ``K`` for ``controller.K`` (see ``long_key``)
SHORT_KEYS = {"x0": "plant.x0", "u0": "controller.u0", "K": "controller.K",
              "mode": "controller.mode", "predictor": "controller.predictor",
              "pad": "controller.pad", "allow_unstable": "controller.allow_unstable"}
#: keys whose value is a vector or a matrix: a single number is a list of one
_VECTOR_KEYS = ("plant.x0", "controller.u0")
_MATRIX_KEYS = ("plant.A", "plant.B", "controller.K", "controller.A", "controller.B")


def long_key(key: str, data: dict) -> str:
    """The loop-file key of ``key`` in a loop of ``data``: a dotted or top-level key as it
    is, a short name (``SHORT_KEYS``; ``A``, ``B`` of the section that holds them) and,
    in a loop around a model file, a model's own parameter (``gain`` for
    ``controller.gain``).

    Examples
    --------
    >>> data = {"T": 1.0, "plant": {"model": "pend.py", "x0": [0.0]}}
    >>> long_key("r", data), long_key("x0", data), long_key("gain", data)
    ('r', 'plant.x0', 'controller.gain')
    """
    if "." in key or key in TOP_KEYS:
        return key
    if key in SHORT_KEYS:
        return SHORT_KEYS[key]
    plant = data.get("plant")
    plant = plant if isinstance(plant, dict) else {}
    ctrl = data.get("controller")
    ctrl = ctrl if isinstance(ctrl, dict) else {}
    if key in ("A", "B"):
        return f"controller.{key}" if "A" in ctrl and "A" not in plant else f"plant.{key}"
    if "model" in plant or "model" in ctrl:
        return f"controller.{key}"
    return key


def _listed(key: str, value):
    """A single number given for a vector or matrix key (``x0=1``, ``K=-2``: one state,
    one input) as a list of one, or one row of one."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    if key in _VECTOR_KEYS:
        return [value]
    return [[value]] if key in _MATRIX_KEYS else value


def _fmu_name(key: str, name: str, table: str = "parameters") -> str:
    """The FMU variable name of ``--set plant.parameters.NAME`` (or ``plant.start.NAME``,
    ``table``): ``NAME`` as it is
    (``fixed.phi0``, ``der(x)``), or inside one pair of quotes (``"fixed.phi0"`` or
    ``'fixed.phi0'``, as a TOML key quotes it).

    Examples
    --------
    >>> _fmu_name("k", "fixed.phi0"), _fmu_name("k", '"fixed.phi0"'), _fmu_name("k", "'a b'")
    ('fixed.phi0', 'fixed.phi0', 'a b')
    """
    name = name.strip()
    if name[:1] in ('"', "'"):
        if len(name) < 3 or name[-1] != name[0] or name[0] in name[1:-1]:
            raise ParameterError(f"--set {key}: the variable name {name} is not allowed: "
                                 "must be one name, in one pair of quotes or none")
        name = name[1:-1]
    if not name:
        raise ParameterError(f"--set {key}: expected plant.{table}.NAME (NAME: the FMU's "
                             "variable)")
    return name


def _split(assignment: str) -> tuple[str, str]:
    name, sep, value = assignment.partition("=")
    if not sep or not name.strip():
        raise ParameterError(f"--set {assignment!r}: expected NAME=VALUE")
    return name.strip(), value


def _top(data: dict, where: str) -> dict:
    """The loop file's top-level values (timing, delays, mode), checked."""
    _check_keys(where, {k: v for k, v in data.items() if k not in SECTIONS}, TOP_KEYS,
                (*OTHER_TABLES, *CHANNEL_TABLES))
    plant = data.get("plant")
    if not isinstance(plant, dict):
        raise ParameterError(f"{where}: a [plant] table is required (A and B, or model)")
    if "T" not in data:
        raise ParameterError(f"{where}: T (the sampling period) is required")
    ctrl = dict(data.get("controller") or {})
    top = dict(plant=plant, ctrl=ctrl, T=check_value("T", data["T"]),
               N=check_value("N", data.get("N", DEFAULTS["N"])),
               r=check_value("r", data.get("r", DEFAULTS["r"])),
               tau=check_value("tau", data.get("tau", DEFAULTS["tau"])))
    for key in ("r_true", "tau_true"):
        top[key] = None if data.get(key) is None else check_value(key, data[key])
    top["stop"] = None if data.get("stop_time") is None else check_value(
        "stop_time", data["stop_time"])
    top["mode"] = check_value("controller.mode", ctrl.get("mode",
                                                          DEFAULTS["controller.mode"]))
    if "fmu" not in plant:
        if ("A" in plant) == ("model" in plant):
            raise ParameterError(f"{where}: [plant] needs one of A and B (LTI), model = "
                                 "\"file.py\" or fmu = \"Plant.fmu\"")
        if "x0" not in plant:
            raise ParameterError(f"{where}: plant.x0 (the initial state) is required")
    return top


def _lti_args(top: dict, where: str, array=_array) -> tuple[dict, tuple[str, str], bool]:
    """The ``lti_design`` arguments of an LTI loop file
    (``[plant] A, B``), its state and input names, and whether the sign guard applies;
    the keys and values checked as ``build`` checks them (``array`` parses a list)."""
    plant, ctrl = top["plant"], top["ctrl"]
    x0 = array("plant.x0", plant["x0"], 1)
    _check_keys(f"{where} [plant]", plant, allowed("plant", "lti"))
    _check_keys(f"{where} [controller]", ctrl, allowed("controller", "lti"))
    if "B" not in plant or "K" not in ctrl:
        raise ParameterError(f"{where}: an LTI loop needs plant.B and controller.K")
    A = array("plant.A", plant["A"], 2)
    B = array("plant.B", plant["B"], 2)
    K = array("controller.K", ctrl["K"], 2)
    u0 = array("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else np.zeros(B.shape[1])
    names = (_ident("plant.state", plant.get("state", DEFAULTS["plant.state"])),
             _ident("plant.input", plant.get("input", DEFAULTS["plant.input"])))
    guard = not _flag("controller.allow_unstable",
                      ctrl.get("allow_unstable", DEFAULTS["controller.allow_unstable"]))
    args = dict(A=A, B=B, K=K, T=top["T"], r=top["r"], tau=top["tau"], N=top["N"],
                mode=top["mode"], x0=x0, u0=u0, r_true=top["r_true"],
                tau_true=top["tau_true"])
    if check_value("controller.pad", ctrl.get("pad", DEFAULTS["controller.pad"])):
        args["pad"] = True  # only where true: an unpadded design's arguments as before
    return args, names, guard


def _lti_last(args: dict, guard: bool) -> None:
    """The checks of an LTI loop file after its design's (zero-order hold's ``tau = l T``
    among them): the sign guard."""
    if guard:
        check_sign(args["A"], args["B"], args["K"], args["T"])


def _lti(top: dict, where: str) -> tuple[LtiPoint, str, str]:
    """The design of an LTI loop file and its state and input names, checked as
    ``build`` checks them: keys, shapes and grid (``lti_design``),
    zero-order hold, the sign guard."""
    args, names, guard = _lti_args(top, where)
    point = lti_design(**args)
    _lti_last(args, guard)
    return point, *names


def design(data: dict, where: str = "loop") -> LtiPoint | None:
    """The design and timing of an LTI loop file's ``data`` without the loop's instances
    (checked as ``build`` checks it; a batch sweep's grid point); ``None`` for a loop
    file that is not LTI, or whose LTI controller pads ``tau`` (``controller.pad``): the
    batch engine has no padded controller, so a sweep builds that point's loop and runs it
    on the per-point engine, its notes saying why (``sweep_batch.lti_point``)."""
    top = _top(data, where)
    plant = top["plant"]
    if "fmu" in plant or "A" not in plant:
        return None
    refuse_channel_data(data, "the batch engine (use --engine inprocess or fmu)", where)
    if _stamped(data):
        raise ParameterError(f"{where}: controller.stamps = true is not supported by the "
                             "batch engine yet (use --engine inprocess or fmu)")
    if _padded(data):
        return None
    return _lti(top, where)[0]


def _padded(data: dict) -> bool:
    """Does the loop file's ``[controller]`` ask the LTI controller to pad ``tau``?"""
    return (data.get("controller") or {}).get("pad", False) is True


def _stamped(data: dict) -> bool:
    """Does the loop file's ``[controller]`` ask for the time-stamp controller?"""
    return (data.get("controller") or {}).get("stamps", False) is True


def designs(datas: list[dict], where: str = "loop") -> LtiBatch | None:
    """``design`` of many resolved points at once (a batch sweep's grid): each point's
    keys and lists are checked as ``build`` checks them (a list shared by the points,
    one no ``--set`` replaced, is parsed once), the design's checks are made vectorized
    (``lti_designs``). ``None`` where the points are not LTI, do not
    stack or some point is refused: check those one by one with ``design``, which
    names what is wrong."""
    parsed: dict[tuple, tuple] = {}

    def array(what: str, value, ndim: int) -> np.ndarray:
        key = (what, id(value), ndim)
        hit = parsed.get(key)
        if hit is None or hit[0] is not value:  # the list itself kept: its id stays its own
            hit = parsed[key] = (value, _array(what, value, ndim))
        return hit[1]

    try:
        points = []
        for data in datas:
            top = _top(data, where)
            if "fmu" in top["plant"] or "A" not in top["plant"] or any(
                    t in data for t in CHANNEL_TABLES) or _stamped(data) or _padded(data):
                return None
            points.append(_lti_args(top, where, array))
        batch = lti_designs([args for args, _, _ in points])
        if batch is not None:
            for args, _, guard in points:
                _lti_last(args, guard)
        return batch
    except ParameterError:
        return None


# -- network channels ([meas_delay], [input_delay]) ----------------------------------------

#: the longest delay trace a channel takes (``delaycomp.fmu.build.TRACE_MAX``, the channel
#: FMU's ``trace[1..L]``, which the tests hold it to)
TRACE_MAX = 10_000
#: the loop's true delay that each channel table's ``delay`` defaults to
_TRUE = {"meas_delay": "r", "input_delay": "tau"}
_CHANNEL_NUMBERS = ("delay", "jitter", "shape", "max_delay", "loss", "p_gb", "p_bg",
                    "loss_good", "loss_bad", "period")
_CHANNEL_WORDS = ("distribution", "loss_model", "policy")


def _true_delay(top: dict, table: str) -> float:
    """The loop's true delay of ``table``'s role: ``r_true`` (else ``r``) or ``tau_true``
    (else ``tau``)."""
    name = _TRUE[table]
    true = top[f"{name}_true"]
    return float(top[name] if true is None else true)


def read_trace(path: Path, where: str) -> tuple[float, ...]:
    """The delays [s] of a trace CSV: the column headed ``delay`` (else the first; a
    file whose first row is a number has no header), an empty cell or ``nan`` a lost
    packet (NaN); at most ``TRACE_MAX`` rows. ``where`` names the key in messages.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "trace.csv"
    >>> _ = f.write_text("time,delay\\n0,0.02\\n1,\\n2,nan\\n3,0.05\\n")
    >>> read_trace(f, "meas_delay.trace")
    (0.02, nan, nan, 0.05)
    """
    import csv

    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise BadFileError(path, f"no such file ({where})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadFileError(path, f"cannot be read ({where}): {exc}") from None
    rows = [row for row in csv.reader(text.splitlines()) if any(c.strip() for c in row)]
    if not rows:
        raise ParameterError(f"{where} = {path.name!r} is not allowed: the file holds no "
                             "delays")
    column, first = 0, rows[0]
    if not _DECIMAL.match(first[0].strip()) and first[0].strip().lower() != "nan":
        names = [c.strip() for c in first]
        column = names.index("delay") if "delay" in names else 0
        rows = rows[1:]
    if not 1 <= len(rows) <= TRACE_MAX:
        raise ParameterError(f"{where} = {path.name!r} ({len(rows)} delays) is not allowed: "
                             f"must hold 1 to {TRACE_MAX} delays")
    delays = []
    for i, row in enumerate(rows):
        cell = row[column].strip() if column < len(row) else ""
        if cell == "" or cell.lower() == "nan":
            delays.append(math.nan)
            continue
        if not _DECIMAL.match(cell) or float(cell) < 0:
            raise ParameterError(f"{where} = {path.name!r}: delay {i + 1} ({cell!r}) is not "
                                 "allowed: must be a finite number >= 0 [s], or empty or nan "
                                 "(a lost packet)")
        delays.append(float(cell))
    return tuple(delays)


def channel_of(table: dict, name: str, base: Path, true_delay: float, where: str = "loop"):
    """The ``delaycomp.maths.channel.Channel`` of a loop file's channel table ``name``
    (``[meas_delay]`` or ``[input_delay]``): its keys and values checked, each refusal one
    line naming ``name.key`` and what is allowed; ``delay`` defaults to the loop's true
    delay ``true_delay`` (with a trace, to the trace's smallest delay).

    Examples
    --------
    >>> from pathlib import Path
    >>> channel_of({"distribution": "uniform", "jitter": 0.05}, "meas_delay", Path("."),
    ...            0.1).bound()
    0.15000000000000002
    >>> channel_of({"loss": 2}, "input_delay", Path("."), 0.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: input_delay.loss = 2.0 is not allowed: must be a ...
    """
    from delaycomp.maths.channel import Channel

    if not isinstance(table, dict):
        raise ParameterError(f"{where}: {name} must be a table ([{name}])")
    _check_keys(f"{where} [{name}]", table, allowed("channel", "lti"))
    values: dict[str, Any] = {}
    for key in _CHANNEL_NUMBERS:
        if key in table:
            values[key] = _real(f"{name}.{key}", table[key])
    for key in _CHANNEL_WORDS:
        if key in table:
            if not isinstance(table[key], str):
                raise ParameterError(f"{name}.{key} = {table[key]!r} is not allowed: must be "
                                     "a string")
            values[key] = table[key]
    if "seed" in table:
        seed = table["seed"]
        if isinstance(seed, float) and seed.is_integer():  # --set seed=3 reads 3.0
            seed = int(seed)
        values["seed"] = seed
    if "trace" in table:
        given = table["trace"]
        if isinstance(given, (list, tuple)):  # the delays themselves (the API's Channel)
            trace = tuple(_real(f"{name}.trace[{i + 1}]", d) if not (
                isinstance(d, float) and math.isnan(d)) else math.nan
                for i, d in enumerate(given))
        elif isinstance(given, str):
            path = Path(given)
            trace = read_trace(path if path.is_absolute() else base / path, f"{name}.trace")
        else:
            raise ParameterError(f"{name}.trace = {given!r} is not allowed: must be a CSV "
                                 "file's path")
        values["trace"] = trace
        if values.get("distribution", "constant") == "trace" and "delay" not in values:
            finite = [d for d in trace if not math.isnan(d)]
            values["delay"] = min(finite) if finite else true_delay
    values.setdefault("delay", float(true_delay))
    channel = Channel(**values)
    try:
        channel.check()
    except ValueError as exc:
        raise ParameterError(f"{name}.{exc}") from None
    if channel.distribution == "trace" and not channel.trace:
        raise ParameterError(f"{name}.trace is required for distribution = 'trace': a CSV "
                             "file of measured delays")
    return channel


def channel_parameters(channel, u0_params: dict) -> dict:
    """The channel FMU's parameter values (``fmus/delay/README.md``) of ``channel``, with
    the delay's input history ``u0[i]`` (``u0_params``)."""
    params: dict[str, Any] = {
        "delay": channel.delay, "distribution": channel.distribution,
        "jitter": channel.jitter, "shape": channel.shape,
        "max_delay": 0.0 if channel.max_delay is None else channel.max_delay,
        "loss_model": channel.loss_model, "loss": channel.loss, "p_gb": channel.p_gb,
        "p_bg": channel.p_bg, "loss_good": channel.loss_good, "loss_bad": channel.loss_bad,
        "policy": channel.policy, "seed": channel.seed, "period": channel.period}
    for i, d in enumerate(channel.trace):
        params[f"trace[{i + 1}]"] = -1.0 if math.isnan(d) else d
    return {**params, **u0_params}


def with_channels(loop: Loop, data: dict, base: Path, where: str = "loop") -> Loop:
    """``loop`` with a network channel in the place of each delay whose role names a table
    of ``data`` (``[meas_delay]``, ``[input_delay]``): the instance becomes the channel
    FMU (``BuiltinFmu("channel", {"n": n, "L": L})``, ``L`` the trace's length, none
    without a trace: the registry's default build) with the
    table's channel and the delay's input history; without those tables, ``loop`` as it
    is."""
    from delaycomp.system.loop import BuiltinFmu

    tables = [t for t in CHANNEL_TABLES if t in data]
    if not tables:
        return loop
    instances = []
    for inst in loop.instances:
        if inst.role not in tables:
            instances.append(inst)
            continue
        src = inst.source
        if not (isinstance(src, BuiltinFmu) and src.kind == "delay"):
            raise ParameterError(f"{where}: [{inst.role}] is not allowed: the loop's "
                                 f"{inst.role} is not delaycomp's delay FMU")
        channel = channel_of(data[inst.role], inst.role, base, float(inst.parameters["delay"]),
                             where)
        u0 = {k: v for k, v in inst.parameters.items() if k.startswith("u0[")}
        config = {"n": int(src.config["n"])}
        if channel.trace:  # the default build (and its file) where there is no trace
            config["L"] = len(channel.trace)
        instances.append(Instance(inst.name, inst.role, BuiltinFmu("channel", config),
                                  channel_parameters(channel, u0)))
    return loop.with_instances(instances)


def refuse_channel_data(data: dict, what: str, where: str = "loop") -> None:
    """``refuse_channel`` for loop-file ``data`` (before a loop is built)."""
    for table in CHANNEL_TABLES:
        if table in data:
            raise ParameterError(f"{where}: the [{table}] channel is not supported by {what} "
                                 "yet")


def build(data: dict, base: Path, name: str = "loop", title: str = "",
          where: str = "loop") -> Loop:
    """The ``Loop`` of a loop file's ``data`` (paths relative to ``base``); a
    ``[meas_delay]`` or ``[input_delay]`` table puts a network channel in that delay's
    place (``with_channels``)."""
    top = _top(data, where)
    plant, ctrl, T, N, r, tau, mode = (top[k] for k in ("plant", "ctrl", "T", "N", "r",
                                                         "tau", "mode"))
    stop = top["stop"]
    common = dict(r_true=top["r_true"], tau_true=top["tau_true"], name=name, title=title,
                  stop_time=stop)
    origin = Origin(data, base)
    if "fmu" in plant:
        loop = _fmu_tolerance(plant, lambda: _fmu_plant(plant, ctrl, base, where, T, N, r,
                                                        tau, mode, common))
    elif "A" in plant:
        point, state, inp = _lti(top, where)
        loop = design_loop(point, state, inp, name=name, title=title, stop_time=stop)
    else:
        model_path, _, args = _model_args(top, base, where)
        loop = model_loop(model_path, T, r, tau, N, **args, **common)
    loop = with_stamps(with_channels(loop, data, base, where), data, where)
    return loop.replace(origin=origin)


def _channel_from(params: Mapping[str, Any]):
    """The ``Channel`` of a channel instance's parameters (``channel_parameters`` read
    back)."""
    from delaycomp.maths.channel import Channel

    trace = tuple(math.nan if v < 0 else v for k, v in sorted(
        ((k, v) for k, v in params.items() if k.startswith("trace[")),
        key=lambda kv: int(kv[0][6:-1])))
    names = ("delay", "distribution", "jitter", "shape", "loss_model", "loss", "p_gb", "p_bg",
             "loss_good", "loss_bad", "policy", "seed", "period")
    return Channel(**{k: params[k] for k in names}, trace=trace,
                   max_delay=params["max_delay"] or None)


def with_stamps(loop: Loop, data: dict, where: str = "loop") -> Loop:
    """``loop`` with the time-stamp controller where ``[controller] stamps = true``: an
    LTI loop's controller becomes ``BuiltinFmu("stamped_controller", ...)`` (parameters
    ``T``, ``tau``, ``age_max``, ``mode``, ``A``, ``B``, ``K``, ``u0``), a model loop's
    zero-order-hold controller ``ModelFmu("stamped_model_controller", model)`` (``T``,
    ``tau``, ``age_max``, ``mode``, ``tolerance``, ``u0``, the model's parameters); its
    input ``stamp`` connected to the measurement channel's (a constant channel in the
    place of a plain measurement delay); otherwise ``loop`` as it is."""
    from delaycomp.system.loop import BuiltinFmu, Connection, ModelFmu, Port

    ctrl_data = data.get("controller") or {}
    if not check_value("controller.stamps", ctrl_data.get("stamps", False),
                       f"{where}: controller.stamps"):
        if "age_max" in ctrl_data:
            raise ParameterError(f"{where}: controller.age_max is not allowed without "
                                 "controller.stamps = true")
        return loop
    ctrl, meas = loop.by_role("controller"), loop.by_role("meas_delay")
    model = (ctrl.source.model if ctrl is not None and isinstance(ctrl.source, ModelFmu)
             and ctrl.source.kind == "model_controller" else None)
    if not (ctrl is not None and meas is not None
            and (model is not None or (isinstance(ctrl.source, BuiltinFmu)
                                       and ctrl.source.kind == "controller"))
            and isinstance(meas.source, BuiltinFmu)
            and meas.source.kind in ("delay", "channel")):
        raise ParameterError(f"{where}: controller.stamps = true is not allowed for this "
                             "loop: the time-stamp controller is an LTI loop's ([plant] A, B) "
                             "or a zero-order-hold model loop's ([plant] model)")
    if model is not None:
        _stamped_model_control(model, where)
    if meas.source.kind == "delay":  # a constant channel: the same numbers, and a stamp
        from delaycomp.maths.channel import Channel

        u0 = {k: v for k, v in meas.parameters.items() if k.startswith("u0[")}
        meas = Instance(meas.name, meas.role,
                        BuiltinFmu("channel", {"n": int(meas.source.config["n"])}),
                        channel_parameters(Channel(delay=float(meas.parameters["delay"])),
                                           u0))
    T = float(ctrl.parameters["T"])
    age_max = ctrl_data.get("age_max")
    age_max = (_channel_from(meas.parameters).bound() + T if age_max is None
               else check_value("controller.age_max", age_max, f"{where}: controller.age_max"))
    source: BuiltinFmu | ModelFmu
    if model is None:
        assert isinstance(ctrl.source, BuiltinFmu)  # checked above
        # pad: the time-stamp controller predicts over any tau, as the model branch's
        params = {k: v for k, v in ctrl.parameters.items() if k not in ("r", "pad")}
        source = BuiltinFmu("stamped_controller", dict(ctrl.source.config))
    else:  # the model controller's settings that the time-stamp controller has
        params = {k: v for k, v in ctrl.parameters.items()
                  if k not in ("r", "N", "pad", "predictor", "mode") and not k.startswith("z0[")}
        params["mode"] = ("uncompensated" if ctrl.parameters.get("predictor") == "none"
                          else "compensated")
        source = ModelFmu("stamped_model_controller", model)
    params["age_max"] = float(age_max)
    stamped = Instance(ctrl.name, ctrl.role, source, params)
    instances = [stamped if i.name == ctrl.name else meas if i.name == meas.name else i
                 for i in loop.instances]
    wire = Connection(Port(meas.name, "stamp"), Port(ctrl.name, "stamp"))
    return loop.replace(instances=tuple(instances), connections=(*loop.connections, wire))


def _stamped_model_control(model_path, where: str) -> None:
    """A model loop's time-stamp controller holds ``k(x, p)`` over each period: a model
    whose ``CONTROL`` is not ``"zoh"`` is refused in one line naming ``controller.stamps``."""
    from delaycomp.maths.model import load_model

    model = load_model(model_path)
    if model.control != "zoh":
        raise ParameterError(f"{where}: controller.stamps = true is not allowed for model "
                             f"{model.name!r}: its CONTROL is {model.control!r}; the time-stamp "
                             "controller holds k(x, p) over each period (CONTROL = 'zoh')")


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
    return _real(where, value)


def model_path(plant: dict, base: Path) -> Path:
    """The model file of a ``[plant] model = "file.py"`` table (relative to ``base``)."""
    path = Path(str(plant["model"]))
    return path if path.is_absolute() else (base / path).resolve()


def _model_args(top: dict, base: Path, where: str, model=None) -> tuple[Path, Any, dict]:
    """The model file, the model and the ``model_loop`` arguments
    (``x0``, ``u0``, ``params``, ``predictor``, ``tolerance``, ``pad``) of a model loop
    file, its keys and values checked (``model``: the file's model, already loaded)."""
    plant, ctrl = top["plant"], top["ctrl"]
    x0 = check_value("plant.x0", plant["x0"])
    _check_keys(f"{where} [plant]", plant, allowed("plant", "model"))
    path = model_path(plant, base)
    from delaycomp.maths.model import load_model

    model = model if model is not None else load_model(path)
    known = allowed("controller", "model")
    params = {k: v for k, v in ctrl.items() if k not in known}
    for key, value in params.items():
        if key not in model.parameters:
            raise ParameterError(f"{where} [controller]: unknown key {key!r}: allowed are "
                                 f"{', '.join([*known, *model.parameters])}")
        params[key] = model_value(model, key, value)
    u0 = check_value("controller.u0", ctrl["u0"]) if "u0" in ctrl else np.zeros(model.m)
    predictor = ctrl.get("predictor")
    if predictor is not None:
        check_value("controller.predictor", predictor)
    if top["mode"] == "uncompensated":
        predictor = "none"
    tol = ctrl.get("tolerance", plant.get("tolerance"))
    tol = None if tol is None else _real("tolerance", tol, positive=True)
    pad = check_value("controller.pad", ctrl.get("pad", DEFAULTS["controller.pad"]))
    return path, model, dict(x0=x0, u0=u0, params=params, predictor=predictor,
                             tolerance=tol, pad=pad)


def check(data: dict, base: Path, where: str = "loop", model=None) -> None:
    """Check a loop file's ``data`` as ``build`` checks it, without building the loop's
    instances: an LTI loop's design (``design``), a model loop's keys, values, lengths,
    grid and zero-order hold (``check_model_loop``). A loop around a
    plant FMU is checked by building it. ``model``: the model of ``[plant] model``, where
    the caller has it loaded (a grid checks many points of one model)."""
    top = _top(data, where)
    plant = top["plant"]
    if "fmu" in plant:
        build(data, base, where=where)
        return
    for table in CHANNEL_TABLES:
        if table in data:
            channel_of(data[table], table, base, _true_delay(top, table))
    if "A" in plant:
        _lti(top, where)
    else:
        path, model, args = _model_args(top, base, where, model)
        if _stamped(data):
            _stamped_model_control(path, where)
        check_model_loop(model, top["T"], top["r"], top["tau"], top["N"], args["x0"],
                         args["u0"], args["params"], args["pad"], top["r_true"],
                         top["tau_true"])


def _fmu_plant(plant: dict, ctrl: dict, base: Path, where: str, T, N, r, tau, mode,
               common: dict) -> Loop:
    """``[plant] fmu = "Plant.fmu"``: a user's FMU as the plant (``.plantfmu``)."""
    from delaycomp.system.plantfmu import fmu_plant_loop

    _check_keys(f"{where} [plant]", plant, allowed("plant", "fmu-lti"))
    for key in ("states", "inputs", "x0"):
        if key not in plant:
            raise ParameterError(f"{where}: plant.{key} is required with plant.fmu ("
                                 + {"states": "the FMU outputs that form the measured state x",
                                    "inputs": "the FMU inputs that receive u",
                                    "x0": "the history of x on [-r, 0]"}[key] + ")")
    if not isinstance(plant["fmu"], str):
        raise ParameterError(f"plant.fmu = {plant['fmu']!r} is not allowed: must be a path")
    fmu = Path(plant["fmu"])
    fmu = fmu if fmu.is_absolute() else (base / fmu).resolve()
    x0 = _array("plant.x0", plant["x0"], 1)
    if ctrl.get("predictor") == "plant-fmu":
        return _plant_fmu_predictor(plant, ctrl, fmu, where, T, N, r, tau, x0, common)
    if ("A" in ctrl) == ("model" in ctrl):
        raise ParameterError(f"{where}: with plant.fmu the predictor's model comes from "
                             "[controller]: A and B (LTI, with K) or model = \"file.py\"")
    if "A" in ctrl:
        _check_keys(f"{where} [controller]", ctrl, allowed("controller", "fmu-lti"))
        if "B" not in ctrl or "K" not in ctrl:
            raise ParameterError(f"{where}: an LTI predictor needs controller.A, "
                                 "controller.B and controller.K")
        A = _array("controller.A", ctrl["A"], 2)
        B = _array("controller.B", ctrl["B"], 2)
        K = _array("controller.K", ctrl["K"], 2)
        u0 = _array("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else None
        pad = check_value("controller.pad", ctrl.get("pad", DEFAULTS["controller.pad"]))
        loop = fmu_plant_loop(fmu, plant["states"], plant["inputs"],
                              plant.get("parameters"), T, r, tau, N, x0, u0, A=A, B=B, K=K,
                              mode=mode, start=plant.get("start"), pad=pad, **common)
        if not _flag("controller.allow_unstable",
                     ctrl.get("allow_unstable", DEFAULTS["controller.allow_unstable"])):
            check_sign(A, B, K, T)
        return loop
    model_path = Path(str(ctrl["model"]))
    if not model_path.is_absolute():
        model_path = (base / model_path).resolve()
    from delaycomp.maths.model import load_model

    model = load_model(model_path)
    keys = allowed("controller", "fmu-model")
    params = {}
    for key, value in ctrl.items():
        if key in ("model", "u0", "mode"):
            # mode (compensated or not) is the loop's, applied below as predictor = none;
            # the model controller FMU's own "mode" parameter is its model's CONTROL
            continue
        if key not in keys and key not in model.parameters:
            raise ParameterError(f"{where} [controller]: unknown key {key!r}: allowed are "
                                 f"{', '.join([*keys, *model.parameters])}")
        params[key] = (model_value(model, key, value) if key in model.parameters
                       else _real("controller.tolerance", value, positive=True)
                       if key == "tolerance" else check_value(f"controller.{key}", value))
    params.setdefault("pad", DEFAULTS["controller.pad"])
    if mode == "uncompensated":
        params["predictor"] = "none"
    u0 = _array("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else None
    return fmu_plant_loop(fmu, plant["states"], plant["inputs"], plant.get("parameters"),
                          T, r, tau, N, x0, u0, model=model_path,
                          controller_parameters=params, start=plant.get("start"), **common)


def _plant_fmu_predictor(plant: dict, ctrl: dict, fmu: Path, where: str, T, N, r, tau,
                         x0, common: dict) -> Loop:
    """``predictor = "plant-fmu"``: the plant FMU's Model Exchange derivatives as the
    predictor's model (``.fmumodel``), its state found from the measured outputs, with
    ``u = K y``."""
    from delaycomp.maths.predictors import DEFAULT_TOL
    from delaycomp.system.fmumodel import start_from_outputs, write_model
    from delaycomp.system.plantfmu import (
        check_mapping,
        check_output_map,
        fmu_plant_loop,
        histories,
        read_interface,
    )

    _check_keys(f"{where} [controller]", ctrl, allowed("controller", "fmu-plant-fmu"))
    if "K" not in ctrl:
        raise ParameterError(f"{where}: controller.predictor = \"plant-fmu\" needs "
                             "controller.K (u = K x)")
    iface = read_interface(fmu)
    if iface.model_exchange is None:
        raise ParameterError(f"controller.predictor = \"plant-fmu\" is not allowed: "
                             f"{fmu.name} has no Model Exchange interface (give A and B, or "
                             "model)")
    states, inputs, values = check_mapping(iface, plant["states"], plant["inputs"],
                                           plant.get("parameters"), start=plant.get("start"))
    check_output_map(iface, states)
    K = _array("controller.K", ctrl["K"], 2)
    tol = DEFAULT_TOL
    if "tolerance" in ctrl:
        tol = _real("controller.tolerance", ctrl["tolerance"], positive=True)
        if not tol < 1:
            raise ParameterError(f"controller.tolerance = {tol!r} is not allowed: must be in "
                                 "(0, 1)")
    model = write_model(fmu, states, inputs, iface.states, K, values, tolerance=tol)
    start = plant.get("start")
    x0, _ = histories(x0, None, states, inputs)  # x0 checked before it is inverted
    if start is None and all(iface.variables[x].initial == "exact" for x in iface.states):
        # x0 applied through the start values of the FMU's states, found from the outputs'
        # map (the model module makes the FMI calls)
        start = start_from_outputs(model, fmu.name, x0)
        values = {**values, **start}
        model = write_model(fmu, states, inputs, iface.states, K, values, tolerance=tol)
    mode = ctrl.get("mode", DEFAULTS["controller.mode"])
    params: dict = {"predictor": "none" if mode == "uncompensated" else "closed"}
    u0 = _array("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else None
    check_zoh_delay(tau, T)  # u = K x held over each period; no padding here
    return fmu_plant_loop(fmu, states, inputs, plant.get("parameters"), T, r, tau, N, x0, u0,
                          model=model, controller_parameters=params, start=start, **common)


def _fmu_tolerance(plant: dict, make: Callable[[], Loop]) -> Loop:
    """The loop of a plant FMU (``make()``) with ``[plant] tolerance``, checked first, for
    its ``fmi2SetupExperiment`` (``with_tolerance``)."""
    from delaycomp.system.plantfmu import check_tolerance, with_tolerance

    tol = plant.get("tolerance")
    tol = None if tol is None else check_tolerance(tol)
    return with_tolerance(make(), tol)


def _ident(where: str, value) -> str:
    if not (isinstance(value, str) and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", value)):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be an identifier")
    return value


def read_loop(path: str | Path, assignments: list[str] | dict | None = None) -> Loop:
    """The loop of the file at ``path`` with ``NAME=VALUE`` overrides."""
    return LoopFile(path).loop(assignments)
