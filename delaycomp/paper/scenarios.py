"""Scenarios: named closed loops with their parameters, defaults and allowed ranges.

A scenario turns user parameters into a :class:`~delaycomp.system.Loop` (the typed loop
that every command runs): which FMU each instance is, its parameter values, the
connections and the recorded signals. It does not run anything.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from delaycomp.errors import ParameterError
from delaycomp.maths.grid import on_grid
from delaycomp.names import MODES, indexed
from delaycomp.system import (
    Loop,
    LtiBatch,
    LtiPoint,
    Timing,
    check_zoh_delay,
    lti_design,
    lti_designs,
    lti_loop,
    model_loop,
)

__all__ = [
    "SCENARIOS",
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


@dataclass(frozen=True)
class Param:
    """A scenario parameter: name, default, how to parse it, and its allowed range."""

    name: str
    default: object
    help: str
    allowed: str
    parse: Callable[[str], object]
    ok: Callable[[Any], bool]


#: ASCII decimal literals only: Python's float() and int() also take other scripts'
#: digits ('١' is 1, '２' is 2) and underscores ('1_000'), which a user did not mean  # noqa: RUF003
_REAL_TEXT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?:inf|nan)",
                        re.ASCII | re.IGNORECASE)
_INT_TEXT = re.compile(r"[+-]?\d+", re.ASCII)


def _real(text: str) -> float:
    if not _REAL_TEXT.fullmatch(text.strip()):
        raise ValueError("not an ASCII decimal number")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError("not finite")
    return value


def _positive_int(text: str) -> int:
    if not _INT_TEXT.fullmatch(text.strip()):
        raise ValueError("not an ASCII decimal integer")
    return int(text)


def real(name, default, help, allowed="a finite number", ok=lambda v: True) -> Param:
    """A finite real parameter, ``ok`` its further range."""
    return Param(name, default, help, allowed, _real, ok)


#: The allowed range of a delay on the base grid (``r``, ``r_true``, ``tau_true``, and
#: ``tau`` under continuous input): what :func:`_check_grid` enforces through
#: :func:`delaycomp.maths.grid.on_grid`, as ``delaycomp list`` and the README say it.
ON_BASE_GRID = "a finite number >= 0, a whole number of base steps h = T/N"
#: ``tau`` under zero-order hold (Theorem 3.2); :data:`ZOH_TAU_PAD` where ``pad=1`` is offered.
ZOH_TAU = "a finite multiple l*T of T, l >= 0"
ZOH_TAU_PAD = f"{ZOH_TAU} (with pad=1: {ON_BASE_GRID})"


def _vector(text: str) -> tuple[float, ...]:
    return tuple(_real(part) for part in text.split(","))


def vector(name, default, help) -> Param:
    """Comma-separated finite numbers (the length is checked by the scenario)."""
    return Param(name, default, help, "comma-separated finite numbers", _vector, lambda v: True)


def choice(name, default, help, options) -> Param:
    """A parameter that takes one of ``options``."""
    return Param(name, default, help, " or ".join(options), str, lambda v: v in options)


def _flag(text: str) -> bool:
    value = text.strip().lower()
    if value in ("1", "true", "yes", "on"):
        return True
    if value in ("0", "false", "no", "off"):
        return False
    raise ValueError(text)


@dataclass(frozen=True)
class Scenario:
    """A named loop of the paper: its parameters with defaults and allowed ranges, the builder of
    its loop, its stop time, its LTI design where it has one."""

    name: str
    title: str
    params: tuple[Param, ...]
    #: validated parameters -> the loop
    builder: Callable[[dict], Loop]
    default_stop_time: float
    check: Callable[[dict], None] = lambda p: None
    #: for LTI scenarios: parameters -> the arguments of :func:`~delaycomp.system.lti_design`
    #: (the builder is then ``lti_loop`` of the same arguments), for :meth:`design`
    lti_args: Callable[[dict], dict] | None = None

    @property
    def lti(self) -> Callable[[dict], tuple] | None:
        """For LTI scenarios: parameters -> ``(A, B, K)`` of ``x' = A x + B u``,
        ``u = K x`` (from :attr:`lti_args`); ``None`` for the others."""
        args = self.lti_args
        if args is None:
            return None
        return lambda p: tuple(args(p)[key] for key in ("A", "B", "K"))

    def make(self, params: dict) -> Loop:
        """The loop for resolved ``params`` (:meth:`resolve`), named after the scenario.

        Its stop time is the scenario's default where that lies on the loop's base grid;
        with a new ``T`` or ``N`` it may not, and the loop then has none (a run names
        ``--stop-time``; critical-delay and sweeps, which choose their own, just work).
        """
        loop = self.builder(params)
        stop = self.default_stop_time
        return loop.replace(name=self.name, title=self.title,
                            stop_time=stop if on_grid(stop, loop.h) else None)

    def loop(self, assignments: list[str] | dict | None = None) -> Loop:
        """The loop for ``NAME=VALUE`` assignments over the defaults."""
        return self.make(self.resolve(assignments))

    def design(self, params: dict) -> LtiPoint | None:
        """For an LTI scenario, the design and timing of resolved ``params`` without the
        loop's instances (validated as :meth:`make` validates them; a batch sweep's grid
        point); ``None`` for the others.

        Examples
        --------
        >>> sc = get("example-3.6")
        >>> pt = sc.design(sc.resolve(["k=1.5"]))
        >>> pt.lti.K.tolist(), pt.timing == sc.loop(["k=1.5"]).timing
        ([[-1.5]], True)
        """
        return None if self.lti_args is None else lti_design(**self.lti_args(params))

    def designs(self, params: list[dict]) -> LtiBatch | None:
        """:meth:`design` of many resolved points at once, as arrays
        (:func:`~delaycomp.system.lti_designs`: the same checks, vectorized); ``None`` for
        a scenario that is not LTI, or points that do not stack or fail a check (validate
        those one by one with :meth:`design`, which names what is wrong)."""
        if self.lti_args is None:
            return None
        return lti_designs([self.lti_args(p) for p in params])

    def param(self, name: str) -> Param:
        """The parameter called ``name`` (ParameterError listing the allowed ones if none)."""
        for p in self.params:
            if p.name == name:
                return p
        names = ", ".join(p.name for p in self.params)
        raise ParameterError(f"unknown parameter {name!r} for {self.name}: allowed are {names}")

    def resolve(self, assignments: list[str] | dict | None = None) -> dict:
        """Defaults overridden by ``NAME=VALUE`` strings (or a dict); validated."""
        values = {p.name: p.default for p in self.params}
        items = assignments.items() if isinstance(assignments, dict) else (
            _split(a) for a in (assignments or []))
        for name, text in items:
            values[name] = self._parse(name, text)
        self.check(values)
        return values

    def _parse(self, name: str, text) -> object:
        """The value of one assignment, checked against its parameter's range."""
        p = self.param(name)
        try:
            value = p.parse(str(text))
        except ValueError:
            raise ParameterError(
                f"parameter {name} = {text!r} is not allowed: must be {p.allowed}") from None
        if not p.ok(value):
            raise ParameterError(
                f"parameter {name} = {text!r} is not allowed: must be {p.allowed}")
        return value

    def resolve_grid(self, sets: list[str], points: list[tuple[str, ...]]) -> list[dict] | None:
        """:meth:`resolve` of ``sets`` followed by each point's assignments, for every
        point of a grid, parsing each distinct assignment once; ``None`` if some point is
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
            base = {p.name: p.default for p in self.params}  # checked per point below
            for text in sets:
                name, value = _split(text)
                base[name] = self._parse(name, value)
            parsed: dict[str, tuple[str, object]] = {}
            out = []
            for texts in points:
                values = dict(base)
                for text in texts:
                    got = parsed.get(text)
                    if got is None:
                        name, value = _split(text)
                        got = parsed[text] = (name, self._parse(name, value))
                    values[got[0]] = got[1]
                self.check(values)
                out.append(values)
            return out
        except ParameterError:
            return None


def _split(assignment: str) -> tuple[str, str]:
    name, sep, value = assignment.partition("=")
    if not sep or not name:
        raise ParameterError(f"--set {assignment!r}: expected NAME=VALUE")
    return name.strip(), value.strip()


def _true_delay_params() -> tuple[Param, ...]:
    return (
        Param("r_true", None, "the loop's true measurement delay (default: r, the one the "
              "controller assumes)", ON_BASE_GRID, _real, lambda v: v >= 0),
        Param("tau_true", None, "the loop's true input delay (default: tau)",
              ON_BASE_GRID, _real, lambda v: v >= 0),
    )


# -- Example 3.6 ----------------------------------------------------------------------

def _check_timing(p: dict) -> None:
    """Cross-parameter rules shared by the LTI scenarios."""
    check_zoh_delay(p["tau"], p["T"])
    _check_grid(p, zoh=False)


def _example_3_6_args(p: dict) -> dict:
    return dict(A=[[1.0]], B=[[1.0]], K=[[-p["k"]]], T=p["T"], r=p["r"], tau=p["tau"],
                N=p["N"], mode=p["mode"], x0=[p["x0"]], u0=[p["u0"]], r_true=p["r_true"],
                tau_true=p["tau_true"])


def _example_3_6(p: dict) -> Loop:
    return lti_loop(**_example_3_6_args(p))


def _mode_param() -> Param:
    return Param("mode", "compensated", "controller: u = K Phi(y) or u = K y",
                 " or ".join(MODES), str, lambda v: v in MODES)


EXAMPLE_3_6 = Scenario(
    name="example-3.6",
    title="Example 3.6: x' = x + u, u = -k x under ZOH, measurement delay r",
    params=(
        real("k", 2.0, "feedback gain, u = -k x"),
        real("T", 1.0, "sampling period", "a finite number > 0", lambda v: v > 0),
        real("r", 0.3, "measurement delay", ON_BASE_GRID, lambda v: v >= 0),
        real("tau", 0.0, "input delay", ZOH_TAU, lambda v: v >= 0),
        Param("N", 100, "base steps per sampling period (h = T/N)", "a positive integer",
              _positive_int, lambda v: v >= 1),
        _mode_param(),
        real("x0", 1.0, "constant history of x on [-r, 0]"),
        real("u0", 0.0, "constant input history on [-r - tau, 0)"),
        *_true_delay_params(),
    ),
    builder=_example_3_6,
    default_stop_time=20.0,
    check=_check_timing,
    lti_args=_example_3_6_args,
)

# -- the nonlinear examples and Corollary 3.7 -------------------------------------------

def _timing_params(T, r, tau, tau_allowed: str, N=100) -> tuple[Param, ...]:
    return (
        real("T", T, "sampling period", "a finite number > 0", lambda v: v > 0),
        real("r", r, "measurement delay", ON_BASE_GRID, lambda v: v >= 0),
        real("tau", tau, "input delay", tau_allowed, lambda v: v >= 0),
        Param("N", N, "base steps per sampling period (h = T/N)", "a positive integer",
              _positive_int, lambda v: v >= 1),
        *_true_delay_params(),
    )


def _history_params(x0, u0) -> tuple[Param, ...]:
    return (vector("x0", x0, "initial state, comma-separated in state order, constant "
                             "on [-r, 0]"),
            vector("u0", u0, "input history, comma-separated, constant on [-r - tau, 0)"))


_PREDICTOR = choice("predictor", "closed", "predictor map: the closed form or an ODE solve",
                    ("closed", "numerical"))
_PAD = Param("pad", False, "pad tau up to the next multiple of T (Remark 3.3(b))",
             "0 or 1", _flag, lambda v: True)


def _check_grid(p: dict, zoh: bool) -> None:
    """The delays on the base grid (:meth:`Timing.check_on_grid`) and, under zero-order
    hold without padding, ``tau = l T`` (:func:`check_zoh_delay`)."""
    timing = Timing(p["T"], p["N"])
    for name in ("r", "tau", "r_true", "tau_true"):
        if p.get(name) is not None:
            timing.check_on_grid(name, p[name])
    if zoh and not p.get("pad"):
        # only a scenario that has the pad parameter suggests it (corollary-3.7 has none)
        check_zoh_delay(p["tau"], p["T"], padding="pad" in p)


def _check_lengths(p: dict, n: int, m: int, states, inputs) -> None:
    for name, want, names in (("x0", n, states), ("u0", m, inputs)):
        if len(p[name]) != want:
            raise ParameterError(f"parameter {name} has {len(p[name])} values: must have "
                                 f"{want} ({', '.join(names)})")


def _model_scenario(name: str, title: str, module: str, defaults: dict, own: tuple,
                    stop: float, states, inputs, zoh: bool) -> Scenario:
    from delaycomp.paper.models import path

    def check(p):
        _check_grid(p, zoh)
        _check_lengths(p, len(states), len(inputs), states, inputs)

    def make(p):
        params = {key: p[key] for key in ("law", "p") if key in p}
        return model_loop(path(module), p["T"], p["r"], p["tau"], p["N"], p["x0"], p["u0"],
                          params=params, predictor=p["predictor"],
                          pad=p.get("pad", False), r_true=p["r_true"],
                          tau_true=p["tau_true"])

    tau_allowed = ZOH_TAU_PAD if zoh else ON_BASE_GRID
    params = (*_timing_params(defaults["T"], defaults["r"], defaults["tau"], tau_allowed),
              *_history_params(defaults["x0"], defaults["u0"]), _PREDICTOR,
              *((_PAD,) if zoh else ()), *own)
    return Scenario(name, title, params, make, stop, check)


EXAMPLE_2_4 = _model_scenario(
    "example-2.4",
    "Example 2.4: strict-feedforward system (2.15), continuous input, corrected (2.18)",
    "example_2_4", dict(T=0.5, r=0.3, tau=0.7, x0=(1.0, -1.0, 0.5), u0=(0.0,)),
    (choice("law", "corrected", "feedback (2.18): corrected (errata) or as printed",
            ("corrected", "printed")),),
    30.0, ("x1", "x2", "x3"), ("u",), zoh=False)

EXAMPLE_3_8 = _model_scenario(
    "example-3.8",
    "Example 3.8: x1' = x2 + p(x2) u, x2' = u under ZOH, dead-beat (3.25)/(3.29)",
    "example_3_8", dict(T=1.0, r=0.5, tau=0.0, x0=(1.0, -1.0), u0=(0.0,)),
    (choice("p", "square", "p(w) = w^2 (square) or sin(w) (sin)", ("square", "sin")),),
    10.0, ("x1", "x2"), ("u",), zoh=True)

PROPOSITION_4_2 = _model_scenario(
    "proposition-4.2",
    "Proposition 4.2: unicycle, ZOH on (v, omega), dead-beat (corrected law)",
    "proposition_4_2", dict(T=1.0, r=0.5, tau=1.0, x0=(1.0, 1.0, 0.5), u0=(0.0, 0.0)),
    (choice("law", "corrected", "ZOH law: corrected (errata) or as printed (4.9)-(4.11)",
            ("corrected", "printed")),),
    10.0, ("x", "y", "theta"), ("v", "omega"), zoh=True)


COROLLARY_4_1 = _model_scenario(
    "corollary-4.1",
    "Corollary 4.1: unicycle, continuous input, Pomet's time-periodic stabilizer",
    "corollary_4_1", dict(T=0.5, r=0.2, tau=0.3, x0=(1.0, 1.0, 0.5), u0=(0.0, 0.0)),
    (), 100.0, ("x", "y", "theta"), ("v", "omega"), zoh=False)


def _chain_x0(n: int) -> tuple[float, ...]:
    return tuple((1.0, -1.0, 0.5)[i % 3] for i in range(n))


def _corollary_3_7_check(p: dict) -> None:
    if p["x0"] is None:
        p["x0"] = _chain_x0(p["n"])
    _check_grid(p, zoh=True)
    _check_lengths(p, p["n"], 1, indexed("x", p["n"]), ("u",))


def _corollary_3_7_args(p: dict) -> dict:
    from delaycomp.maths.predictors import deadbeat_gain

    n = p["n"]
    return dict(A=np.eye(n, k=1), B=np.eye(n)[:, -1:], K=deadbeat_gain(n, p["T"]), T=p["T"],
                r=p["r"], tau=p["tau"], N=p["N"], mode=p["mode"], x0=p["x0"], u0=p["u0"],
                r_true=p["r_true"], tau_true=p["tau_true"])


def _corollary_3_7(p: dict) -> Loop:
    return lti_loop(**_corollary_3_7_args(p))


COROLLARY_3_7 = Scenario(
    name="corollary-3.7",
    title="Corollary 3.7: chain of n integrators under ZOH, dead-beat gain for period T",
    params=(
        Param("n", 3, "number of integrators", "an integer from 1 to 12", _positive_int,
              lambda v: 1 <= v <= 12),
        *_timing_params(1.0, 0.5, 1.0, ZOH_TAU),
        Param("x0", None, "initial state, comma-separated (default 1,-1,0.5,1,... of length "
                          "n), constant on [-r, 0]", "comma-separated finite numbers",
              _vector, lambda v: True),
        vector("u0", (0.0,), "input history, constant on [-r - tau, 0)"),
        _mode_param(),
    ),
    builder=_corollary_3_7,
    default_stop_time=10.0,
    check=_corollary_3_7_check,
    lti_args=_corollary_3_7_args,
)

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    EXAMPLE_3_6, EXAMPLE_2_4, EXAMPLE_3_8, COROLLARY_3_7, COROLLARY_4_1, PROPOSITION_4_2)}


def get(name: str) -> Scenario:
    """The scenario called ``name`` (ParameterError listing the scenarios if none)."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ParameterError(
            f"unknown scenario {name!r}: allowed are {', '.join(SCENARIOS)}") from None


#: the scenarios at their defaults, as loop files shipped in the package
LOOPS_DIR = Path(__file__).resolve().parent / "loops"


def loop_file(name: str) -> Path:
    """The shipped loop file of scenario ``name`` at its defaults (a starting point for
    one's own; it builds the same loop as the scenario, tested)."""
    get(name)
    return LOOPS_DIR / f"{name}.toml"


def open_source(text: str | Path):
    """A scenario by name, or a loop file (a path ending in ``.toml``).

    Both give ``name``, ``title``, ``default_stop_time`` (``None`` when a loop file has
    none), ``resolve(assignments)``, ``make(resolved) -> Loop`` and ``loop(assignments)``.
    """
    if str(text).endswith(".toml"):
        from delaycomp.system.loopfile import LoopFile

        return LoopFile(text)
    return get(str(text))
