"""Scenarios: the paper's closed loops by name, each its shipped loop file with short names.

A scenario is a loop file in ``delaycomp/paper/loops/`` (the paper as data: the matrices
or the model file, the timing, the histories) read by the loop-file reader
(``delaycomp.system.loopfile``), which parses and checks every value, plus an alias
table: each scenario parameter (``k``, ``T``, ``x0``, ``law``) names the loop-file key it
sets (``k`` is ``controller.K = [[-k]]``) and how its value maps to the key's. Defaults are
the file's values; the allowed ranges are the reader's. A scenario turns ``NAME=VALUE``
assignments into a ``Loop``; it does not run anything.

Importing this module imports no numpy (nor the loop-file reader, which uses it): naming a
scenario, refusing an unknown one or a parameter it does not have, and what ``delaycomp
list`` prints (``Scenario.listing``) stay light; reading a loop file and building a loop
import the reader on first use.
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from delaycomp.errors import ParameterError, short, shown
from delaycomp.maths.grid import on_grid
from delaycomp.system.loopkeys import ALLOWED, ON_BASE_GRID, ZOH_TAU, ZOH_TAU_PAD

if TYPE_CHECKING:
    from delaycomp.system import Loop, LtiBatch, LtiPoint, lti_loop, model_loop
    from delaycomp.system.loopfile import LoopFile

__all__ = [
    "ON_BASE_GRID",
    "SCENARIOS",
    "ZOH_TAU",
    "ZOH_TAU_PAD",
    "Loop",
    "Param",
    "ParameterError",
    "Scenario",
    "get",
    "loop_file",
    "lti_loop",
    "model_loop",
    "on_grid",
    "open_source",
]

#: the names this module gives from ``delaycomp.system`` (imported on first access, PEP 562)
_SYSTEM = ("Loop", "lti_loop", "model_loop")


def __getattr__(name: str):
    """``Loop``, ``lti_loop`` and ``model_loop``, from ``delaycomp.system``."""
    if name in _SYSTEM:
        return getattr(importlib.import_module("delaycomp.system"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _reader():
    """The loop-file reader, ``delaycomp.system.loopfile`` (numpy), imported on first use."""
    from delaycomp.system import loopfile

    return loopfile


#: the scenarios at their defaults, as loop files shipped in the package
LOOPS_DIR = Path(__file__).resolve().parent / "loops"

#: distinct values remembered per parameter (``Scenario._file_value``)
_MEMO_SIZE = 4096
#: no default in the alias: the loop file's value is the default
_FROM_FILE: Any = object()


@dataclass(frozen=True)
class Param:
    """A scenario parameter: an alias of one loop-file key.

    ``key`` is the key it sets (``"controller.K"``; ``None``: it sets keys through the
    scenario's ``derive``), ``to_file`` maps the parameter's value to the key's (``k`` to
    ``[[-k]]``) and ``from_file`` the key's checked value back (the default shown by
    ``delaycomp list`` is the file's value read so). ``allowed`` is the range in words
    (``None``: the reader's, ``delaycomp.system.loopkeys.ALLOWED``; a model's own
    parameter states its choices, which ``delaycomp list`` prints without importing the
    model, tested equal to the model's). The reader checks every value; a refusal names
    this parameter. A parameter without a key (Corollary 3.7's ``n``) has its own
    ``check``.
    """

    name: str
    help: str
    key: str | None = None
    allowed: str | None = None
    to_file: Callable[[Any], Any] | None = None
    from_file: Callable[[Any], Any] | None = None
    default: Any = _FROM_FILE
    #: for a parameter without ``key``: its value checked (``derive`` uses it)
    check: Callable[[Any], Any] | None = None


def _number(value) -> float:
    """A number given to an alias that wraps it (``k``, a scalar ``x0``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError("not a number")
    return float(value)


def _listed(value):
    """A single number given for a list key (``u0=0``) as a list of one."""
    return [value] if isinstance(value, (int, float)) and not isinstance(value, bool) else value


def _vector(value) -> tuple[float, ...]:
    return tuple(float(v) for v in value)


def _zero_one(value):
    """``pad=1`` and ``pad=0`` (as ``delaycomp list`` says) for the file's true/false."""
    return {0.0: False, 1.0: True}.get(value, value) if not isinstance(value, bool) else value


def _timing(tau_allowed: str) -> tuple[Param, ...]:
    return (
        Param("T", "sampling period", "T"),
        Param("r", "measurement delay", "r"),
        Param("tau", "input delay", "tau", allowed=tau_allowed),
        Param("N", "base steps per sampling period (h = T/N)", "N"),
    )


_TRUE_DELAYS = (
    Param("r_true", "the loop's true measurement delay (default: r, the one the controller "
          "assumes)", "r_true", default=None),
    Param("tau_true", "the loop's true input delay (default: tau)", "tau_true", default=None),
)
_MODE = Param("mode", "controller: u = K Phi(y) or u = K y", "controller.mode")


def _histories() -> tuple[Param, ...]:
    return (
        Param("x0", "initial state, comma-separated in state order, constant on [-r, 0]",
              "plant.x0", to_file=_listed, from_file=_vector),
        Param("u0", "input history, comma-separated, constant on [-r - tau, 0)",
              "controller.u0", to_file=_listed, from_file=_vector),
    )


class Scenario:
    """A named loop of the paper: its shipped loop file and the alias table of its
    parameters.

    Parameters
    ----------
    name : str
        The scenario's name, also its loop file's stem in ``LOOPS_DIR``.
    params : tuple of Param
        The alias table, in the order ``delaycomp list`` shows it.
    derive : callable, optional
        ``derive(values) -> {key: value}``: loop-file keys that follow from several
        parameters (Corollary 3.7's matrices and gain from ``n`` and ``T``); it may fill in
        a parameter left ``None`` (its ``x0`` follows ``n``).
    study : dict, optional
        Loop-file keys the scenario sets beyond its file (the LTI scenarios allow unstable
        gains: a sweep over ``k`` crosses into instability).
    """

    def __init__(self, name: str, params: tuple[Param, ...],
                 derive: Callable[[dict], dict] | None = None, study: dict | None = None):
        self.name = name
        self._aliases = params
        self._derive = derive
        self._study = dict(study or {})
        self._memo: dict[str, dict] = {}

    def __repr__(self) -> str:
        return f"Scenario({self.name!r})"

    @functools.cached_property
    def file(self) -> LoopFile:
        """The shipped loop file (read once)."""
        return _reader().LoopFile(LOOPS_DIR / f"{self.name}.toml")

    @property
    def title(self) -> str:
        """The title, from the loop file."""
        return self.file.title

    @property
    def default_stop_time(self) -> float:
        """The stop time of a run that names none, from the loop file."""
        stop = self.file.default_stop_time
        assert stop is not None  # every shipped file has one (tested)
        return stop

    @functools.cached_property
    def model(self):
        """The model of a model scenario (``delaycomp.maths.model``), ``None`` for LTI."""
        plant = self.file.data["plant"]
        if "model" not in plant:
            return None
        from delaycomp.maths.model import load_model

        return load_model(_reader().model_path(plant, self.file.base))

    @functools.cached_property
    def params(self) -> tuple[Param, ...]:
        """The parameters, each with its default and allowed range filled in."""
        check = _reader().check_value  # a model's own parameter is checked when resolved
        return self._filled(self.file.data, lambda key, value: (
            check(key, value) if key in ALLOWED else value))

    def listing(self) -> Listing:
        """What ``delaycomp list`` shows of the scenario, from its shipped file as TOML
        holds it (no loop-file reader, no numpy: the file's numbers as they are, a list's
        as floats): the same as the reader's ``title``, ``default_stop_time`` and
        ``params`` (``tests/test_start.py``), and the reader's checks of the shipped
        files are ``tests/test_scenarios.py``'s.

        Examples
        --------
        >>> shown = get("example-3.6").listing()
        >>> shown.title[:12], shown.stop_time, shown.params[0].default
        ('Example 3.6:', 20.0, 2.0)
        """
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10: the same parser, as the tomli package
            import tomli as tomllib

        with open(LOOPS_DIR / f"{self.name}.toml", "rb") as f:
            data = tomllib.load(f)
        title = str(data.get("title") or f"loop file {self.name}.toml")  # as LoopFile's
        return Listing(title, float(data["stop_time"]),
                       self._filled(data, lambda key, value: _plain(value)))

    def _filled(self, data: dict, check: Callable[[str, Any], Any]) -> tuple[Param, ...]:
        """The alias table with each default read from the file's ``data`` (its value
        ``check``-ed by key) and each allowed range filled in."""
        return tuple(replace(p, default=self._default(p, data, check),
                             allowed=self._allowed(p)) for p in self._aliases)

    @staticmethod
    def _default(p: Param, data: dict, check: Callable[[str, Any], Any]):
        if p.default is not _FROM_FILE or p.key is None:
            return p.default
        value = check(p.key, _get(data, p.key))
        return p.from_file(value) if p.from_file else value

    @staticmethod
    def _allowed(p: Param) -> str:
        if p.allowed is not None:
            return p.allowed
        return ALLOWED[str(p.key)]  # the others state theirs

    def _check_key(self, key, value):
        """``value`` of loop-file ``key`` checked by the reader (a model's own parameter
        against the model)."""
        lf = _reader()
        if key in lf.KEYS:
            return lf.check_value(key, value)
        return lf.model_value(self.model, key.partition(".")[2], value)

    def _known(self, name: str) -> None:
        """A parameter called ``name`` exists (ParameterError listing them if not): the
        alias table alone says so, without reading the file."""
        if not any(p.name == name for p in self._aliases):
            names = ", ".join(p.name for p in self._aliases)
            raise ParameterError(
                f"unknown parameter {name!r} for {self.name}: allowed are {names}")

    def param(self, name: str) -> Param:
        """The parameter called ``name`` (ParameterError listing the allowed ones if none)."""
        self._known(name)
        return next(p for p in self.params if p.name == name)

    def _parse(self, name: str, text) -> object:
        """The value of one assignment, parsed and checked by the loop-file reader as the
        key it stands for; a refusal names the parameter and its range."""
        p = self.param(name)
        lf = _reader()
        try:
            value = lf.parse_value(text) if isinstance(text, str) else text
            if p.key is None:
                return p.check(value) if p.check else value
            value = self._check_key(p.key, p.to_file(value) if p.to_file else value)
            value = p.from_file(value) if p.from_file else value
        except (ParameterError, ValueError, TypeError, RecursionError):
            quoted = repr(shown(text)) if isinstance(text, str) else repr(text)
            raise ParameterError(
                f"parameter {name} = {quoted} is not allowed: must be {p.allowed}") from None
        import numpy as np  # imported by the reader

        if isinstance(value, np.ndarray):  # as the reader keeps it, as a tuple here
            return _vector(value)
        return value

    def data(self, params: dict) -> dict:
        """The loop-file data of resolved ``params``: the file's, each parameter written
        to its key, the derived keys and the scenario's own."""
        data = {k: dict(v) if isinstance(v, dict) else v for k, v in self.file.data.items()}
        data.pop("stop_time", None)  # the scenario's stop time is applied by make
        for p in self._aliases:
            value = params.get(p.name)
            if p.key is not None and value is not None:
                _set(data, p.key, self._file_value(p, value))
        for key, value in {**(self._derive(params) if self._derive else {}),
                           **self._study}.items():
            _set(data, key, value)
        return data

    def _file_value(self, p: Param, value):
        """The key's value of parameter ``p``'s ``value``, one object per distinct value (the
        reader parses a list it has seen once: ``designs``)."""
        memo = self._memo.setdefault(p.name, {})
        key = repr(value)  # not the value: 0.0 == -0.0, and K = [[-k]] keeps the sign
        got = memo.get(key)
        if got is None:
            if len(memo) >= _MEMO_SIZE:
                memo.clear()
            got = memo[key] = p.to_file(value) if p.to_file else (
                list(value) if isinstance(value, tuple) else value)
        return got

    def _values(self, base: dict, texts, parsed: dict | None = None,
                derive: bool = True) -> dict:
        """``base`` with the ``NAME=VALUE`` items of ``texts`` (strings or pairs) parsed,
        then (``derive``) what follows from them filled in; ``parsed`` remembers each
        distinct text's value across grid points."""
        values = dict(base)
        for text in texts:
            got = parsed.get(text) if parsed is not None else None
            if got is None:
                name, value = _split(text) if isinstance(text, str) else text
                got = (name, self._parse(name, value))
                if parsed is not None:
                    parsed[text] = got
            values[got[0]] = got[1]
        if derive and self._derive is not None:
            self._derive(values)  # fills in what follows from the others (and checks it)
        return values

    def resolve(self, assignments: list[str] | dict | None = None) -> dict:
        """Defaults overridden by ``NAME=VALUE`` strings (or a dict), each checked by the
        loop-file reader, then the whole loop checked as it will be built."""
        items = list(assignments.items()) if isinstance(assignments, dict) else list(
            assignments or [])
        for item in items:  # the names first: refused without reading the file
            self._known(_split(item)[0] if isinstance(item, str) else item[0])
        values = self._values({p.name: p.default for p in self.params}, items)
        _reader().check(self.data(values), self.file.base, where=self.file.path.name,
                        model=self.model)
        return values

    def resolve_grid(self, sets: list[str], points: list[tuple[str, ...]]) -> Grid | None:
        """``resolve`` of ``sets`` followed by each point's assignments, for every
        point of a grid, parsing each distinct assignment once (an LTI grid is checked
        at once, ``designs``); ``None`` if some point is
        refused (resolve the points one by one to name it).

        Examples
        --------
        >>> sc = get("example-3.6")
        >>> grid = sc.resolve_grid(["mode=uncompensated"], [("k=1", "r=0"), ("k=1", "r=0.5")])
        >>> grid == [sc.resolve(["mode=uncompensated", "k=1", f"r={r}"]) for r in (0, 0.5)]
        True
        >>> sc.resolve_grid([], [("r=0.305",)]) is None   # off the base grid
        True
        """
        try:
            base = self._values({p.name: p.default for p in self.params}, list(sets),
                                derive=False)  # per point below
            parsed: dict = {}
            out = Grid(self._values(base, texts, parsed) for texts in points)
            if self.model is None:  # all at once where the points stack
                out.designs = self.designs(out)
            if out.designs is None:
                for values in out:
                    _reader().check(self.data(values), self.file.base,
                             where=self.file.path.name, model=self.model)
            return out
        except ParameterError:
            return None

    def make(self, params: dict) -> Loop:
        """The loop for resolved ``params`` (``resolve``), named after the scenario.

        Its stop time is the scenario's default where that lies on the loop's base grid;
        with a new ``T`` or ``N`` it may not, and the loop then has none (a run names
        ``--stop-time``; critical-delay and sweeps, which choose their own, just work).
        """
        loop = self.file.make(self.data(params))
        stop = self.default_stop_time
        return loop.replace(stop_time=stop if on_grid(stop, loop.h) else None)

    def loop(self, assignments: list[str] | dict | None = None) -> Loop:
        """The loop for ``NAME=VALUE`` assignments over the defaults."""
        return self.make(self.resolve(assignments))

    def design(self, params: dict) -> LtiPoint | None:
        """For an LTI scenario, the design and timing of resolved ``params`` without the
        loop's instances (validated as ``make`` validates them; a batch sweep's grid
        point); ``None`` for the others.

        Examples
        --------
        >>> sc = get("example-3.6")
        >>> pt = sc.design(sc.resolve(["k=1.5"]))
        >>> pt.lti.K.tolist(), pt.timing == sc.loop(["k=1.5"]).timing
        ([[-1.5]], True)
        """
        return self.file.design(self.data(params))

    def designs(self, params: list[dict]) -> LtiBatch | None:
        """``design`` of many resolved points at once, as arrays
        (``designs``: the same checks, vectorized); ``None``
        for a scenario that is not LTI, or points that do not stack or fail a check
        (validate those one by one with ``design``, which names what is wrong)."""
        if isinstance(params, Grid) and params.designs is not None:
            return params.designs  # checked by resolve_grid
        return self.file.designs([self.data(p) for p in params])


@dataclass(frozen=True)
class Listing:
    """What ``delaycomp list`` shows of a scenario (``Scenario.listing``)."""

    title: str
    stop_time: float
    params: tuple[Param, ...]


def _plain(value, listed: bool = False):
    """A value of a loop file as TOML holds it, a list's numbers as floats (as the reader
    reads a vector or a matrix)."""
    if isinstance(value, list):
        return [_plain(v, True) for v in value]
    if listed and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


class Grid(list):
    """The resolved points of a grid (``Scenario.resolve_grid``); for an LTI scenario
    it keeps their designs (``designs``: the check made them), so that
    ``Scenario.designs`` does not make them twice."""

    designs: LtiBatch | None = None


def _get(data: dict, key: str):
    section, dot, name = key.partition(".")
    return data[section][name] if dot else data[key]


def _set(data: dict, key: str, value) -> None:
    section, dot, name = key.partition(".")
    if dot:
        data.setdefault(section, {})[name] = value
    else:
        data[key] = value


def _split(assignment: str) -> tuple[str, str]:
    name, sep, value = assignment.partition("=")
    if not sep or not name:
        raise ParameterError(f"--set {assignment!r}: expected NAME=VALUE")
    return name.strip(), value.strip()


# -- the alias tables ------------------------------------------------------------------------

#: the scenarios' gains are studied across stability: the sign guard is the loop files'
_STUDY = {"controller.allow_unstable": True}

_PAD = Param("pad", "pad tau up to the next multiple of T (Remark 3.3(b))", "controller.pad",
             "0 or 1", to_file=_zero_one, default=False)

EXAMPLE_3_6 = Scenario("example-3.6", (
    Param("k", "feedback gain, u = -k x", "controller.K", "a finite number",
          to_file=lambda k: [[-_number(k)]], from_file=lambda K: float(-K[0][0])),
    *_timing(ZOH_TAU_PAD),
    _MODE,
    _PAD,
    Param("x0", "constant history of x on [-r, 0]", "plant.x0", "a finite number",
          to_file=lambda v: [_number(v)], from_file=lambda x: float(x[0])),
    Param("u0", "constant input history on [-r - tau, 0)", "controller.u0", "a finite number",
          to_file=lambda v: [_number(v)], from_file=lambda u: float(u[0])),
    *_TRUE_DELAYS,
), study=_STUDY)

_PREDICTOR = Param("predictor", "predictor map: the closed form or an ODE solve",
                   "controller.predictor")


def _model_scenario(name: str, zoh: bool, *own: Param) -> Scenario:
    """A scenario around a model file: timing, histories, the predictor, ``pad`` under
    zero-order hold, and the model's own parameters ``own``."""
    return Scenario(name, (*_timing(ZOH_TAU_PAD if zoh else ON_BASE_GRID), *_TRUE_DELAYS,
                           *_histories(), _PREDICTOR, *((_PAD,) if zoh else ()), *own))


EXAMPLE_2_4 = _model_scenario(
    "example-2.4", False,
    Param("law", "feedback (2.18): corrected (errata) or as printed", "controller.law",
          "corrected or printed"))
EXAMPLE_3_8 = _model_scenario(
    "example-3.8", True,
    Param("p", "p(w) = w^2 (square) or sin(w) (sin)", "controller.p", "square or sin"))
PROPOSITION_4_2 = _model_scenario(
    "proposition-4.2", True,
    Param("law", "ZOH law: corrected (errata) or as printed (4.9)-(4.11)", "controller.law",
          "corrected or printed"))
COROLLARY_4_1 = _model_scenario("corollary-4.1", False)


#: Corollary 3.7's chain length: from 1 to 12 integrators (the dead-beat gain's entries
#: grow like n!/T^n: beyond 12 the closed loop is not computed reliably in floating point)
CHAIN_MAX = 12


def _chain_length(n) -> int:
    """Corollary 3.7's ``n``: an integer from 1 to ``CHAIN_MAX``."""
    if isinstance(n, bool) or not isinstance(n, (int, float)) or not (
            math.isfinite(n) and n == int(n) and 1 <= n <= CHAIN_MAX):
        raise ValueError(n)
    return int(n)


def _chain(values: dict) -> dict:
    """Corollary 3.7's keys from ``n`` and ``T``: the chain of ``n`` integrators, its
    dead-beat gain for period ``T``, and ``x0`` (``1, -1, 0.5, 1, ...`` where none is
    given)."""
    import numpy as np

    from delaycomp.maths.predictors import deadbeat_gain

    n = values["n"]
    if values.get("x0") is None:
        values["x0"] = tuple((1.0, -1.0, 0.5)[i % 3] for i in range(n))
    return {"plant.A": np.eye(n, k=1).tolist(), "plant.B": np.eye(n)[:, -1:].tolist(),
            "controller.K": deadbeat_gain(n, values["T"]).tolist()}


COROLLARY_3_7 = Scenario("corollary-3.7", (
    Param("n", "number of integrators", allowed=f"an integer from 1 to {CHAIN_MAX}",
          default=3, check=_chain_length),
    *_timing(ZOH_TAU_PAD),
    *_TRUE_DELAYS,
    Param("x0", "initial state, comma-separated (default 1,-1,0.5,1,... of length n), "
          "constant on [-r, 0]", "plant.x0", to_file=_listed, from_file=_vector, default=None),
    Param("u0", "input history, constant on [-r - tau, 0)", "controller.u0", to_file=_listed,
          from_file=_vector),
    _MODE,
    _PAD,
), derive=_chain, study=_STUDY)

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    EXAMPLE_3_6, EXAMPLE_2_4, EXAMPLE_3_8, COROLLARY_3_7, COROLLARY_4_1, PROPOSITION_4_2)}


def get(name: str) -> Scenario:
    """The scenario called ``name`` (ParameterError listing the scenarios if none)."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ParameterError(
            f"unknown scenario {short(name)}: allowed are {', '.join(SCENARIOS)} (or a "
            "loop file: a path ending in .toml)") from None


def loop_file(name: str) -> Path:
    """The shipped loop file of scenario ``name``: the scenario at its defaults, and a
    starting point for one's own (``delaycomp run FILE.toml`` runs the same loop)."""
    get(name)
    return LOOPS_DIR / f"{name}.toml"


def open_source(source: str | Path | Loop | LoopFile | Scenario):
    """The one reading of what a command or an API call is given as a loop: a
    ``Loop`` (its loop-file data, ``LoopData``), a
    loop file (a path ending in ``.toml``, str or Path) or a scenario by name (an opened
    one passes as it is). Anything else is refused in one short line naming it.

    Each gives ``name``, ``title``, ``default_stop_time`` (``None`` when a loop file has
    none), ``resolve(assignments)``, ``make(resolved) -> Loop`` and ``loop(assignments)``.

    Examples
    --------
    >>> open_source("example-3.6"), open_source(loop_file("example-3.6")).name
    (Scenario('example-3.6'), 'example-3.6')
    >>> open_source(get("example-3.6").loop(["r=0.5"])).loop(["r=0"]).lti.r
    0.0
    >>> open_source(3.5)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: source = float 3.5 is not allowed: give a Loop, ...
    """
    if isinstance(source, (str, Path)):  # a name is looked up without the reader (numpy)
        return _reader().LoopFile(source) if str(source).endswith(".toml") else get(
            str(source))
    lf = _reader()
    if isinstance(source, (lf.LoopFile, Scenario)):
        return source
    if isinstance(source, lf.Loop):
        return lf.LoopData.of(source)
    raise ParameterError(f"source = {short(source)} is not allowed: give a Loop, a loop "
                         "file path or a scenario name")
