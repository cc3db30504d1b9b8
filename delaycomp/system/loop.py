"""The typed description of a closed loop: the one structure every consumer takes.

A ``Loop`` holds

- ``Instance`` objects, each with a **role** (``ROLES``: the plant, the
  measurement delay, the predictor-controller, the input delay) and a **source** (where its
  FMU comes from: ``BuiltinFmu``, one of delaycomp's FMU kinds with its build
  configuration; ``ModelFmu``, the plant or controller FMU of a user's model file;
  ``FmuFile``, an FMU file given as it is) and its parameter values;
- typed ``Connection`` objects between ``Port`` objects;
- the ``Timing`` (``T``, ``N``, integer ticks of ``h = T/N``, decided by
  ``delaycomp.maths.grid``);
- the recorded ports, and for LTI loops the design (``LtiDesign``: ``A``, ``B``,
  ``K``, delays, histories) that exact analyses (lifted model, critical delay, the sign
  guard) read.

Everything is validated once, when the loop is built; consumers (the master wiring, the SSP
writer and reader, the Jacobi variant, the container export, the cross-check, sweeps,
critical delay, the benchmark) read fields and never parse strings. Builders for the
standard four-instance loop are ``lti_loop`` and ``model_loop``.

Examples
--------
>>> loop = lti_loop([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, tau=0.0, N=100,
...                 mode="compensated", x0=[1.0], u0=[0.0])
>>> [i.role for i in loop.instances]
['plant', 'meas_delay', 'controller', 'input_delay']
>>> str(loop.connections[0]), loop.timing.h
('plant.x -> meas_delay.u', 0.01)
>>> loop.by_role("controller").parameters["r"]
0.3
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Union, cast

import numpy as np

from delaycomp.errors import ParameterError
from delaycomp.maths import grid
from delaycomp.names import MODES, indexed

Role = Literal["plant", "meas_delay", "controller", "input_delay"]
#: the roles of a closed loop, in signal order: plant -> meas_delay -> controller ->
#: input_delay -> plant
ROLES: tuple[Role, ...] = ("plant", "meas_delay", "controller", "input_delay")


# -- sources -------------------------------------------------------------------------------

@dataclass(frozen=True)
class BuiltinFmu:
    """One of delaycomp's FMUs: a kind of ``delaycomp.fmu.build.FMUS`` (``plant``,
    ``delay``, ``controller``) and its build configuration (dimensions, names)."""

    kind: str
    config: Mapping[str, Any] = field(default_factory=dict)

    def build_key(self) -> tuple[str, dict]:
        """``(kind, config)`` as ``delaycomp.fmu.build.build_fmu`` takes them."""
        return self.kind, dict(self.config)


@dataclass(frozen=True)
class ModelFmu:
    """The plant (``kind = "model_plant"``) or controller (``"model_controller"``) FMU of
    a user's model file (``delaycomp.maths.model``)."""

    kind: str
    model: Path

    @property
    def config(self) -> dict:
        """The build configuration: the model file's path."""
        return {"model": str(self.model)}

    def build_key(self) -> tuple[str, dict]:
        """``(kind, config)``: what names the FMU in the build cache."""
        return self.kind, self.config


@dataclass(frozen=True)
class FmuFile:
    """An FMU file taken as it is (from an SSP archive, or a user's own FMU).

    ``tolerance``: the relative tolerance handed to the FMU's ``fmi2SetupExperiment``
    (``toleranceDefined = true``), for an FMU that integrates with its own variable-step
    solver (a Modelica tool's export); ``None``: none is defined, the FMU uses its own
    default.
    """

    path: Path
    tolerance: float | None = None

    def build_key(self) -> None:
        """``None``: a user's FMU file is used as it is, never built."""
        return None


Source = Union[BuiltinFmu, ModelFmu, FmuFile]  # noqa: UP007 - isinstance() needs Union


# -- structure -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Port:
    """A variable of an instance: ``instance.variable``."""

    instance: str
    variable: str

    def __str__(self) -> str:
        return f"{self.instance}.{self.variable}"


@dataclass(frozen=True)
class Connection:
    """A signal from an output port to an input port."""

    src: Port
    dst: Port

    def __str__(self) -> str:
        return f"{self.src} -> {self.dst}"

    @classmethod
    def parse(cls, text: str) -> Connection:
        """From ``"plant.x -> delay.u"`` (``__str__`` read back).

        Examples
        --------
        >>> c = Connection.parse("plant.x -> meas_delay.u")
        >>> c.src, str(c)
        (Port(instance='plant', variable='x'), 'plant.x -> meas_delay.u')
        """
        left, sep, right = text.partition("->")
        ends = [part.strip().split(".", 1) for part in (left, right)]
        if not sep or any(len(e) != 2 or not all(e) for e in ends):
            raise ValueError(f"connection {text!r} is not allowed: must be "
                             "'instance.variable -> instance.variable'")
        return cls(Port(*ends[0]), Port(*ends[1]))


@dataclass(frozen=True)
class Instance:
    """A component of the loop: its name, role, source and parameter values."""

    name: str
    role: Role
    source: Source
    parameters: Mapping[str, Any] = field(default_factory=dict)

    def with_parameters(self, **changes) -> Instance:
        """A copy with some parameters changed (or added)."""
        return dataclasses.replace(self, parameters={**self.parameters, **changes})


@dataclass(frozen=True)
class Timing:
    """The base grid: sampling period ``T`` and ``N`` base steps per period."""

    T: float
    N: int

    def __post_init__(self):
        if not (isinstance(self.T, (int, float)) and math.isfinite(self.T) and self.T > 0):
            raise ParameterError(f"parameter T = {self.T!r} is not allowed: must be a finite "
                                 "number > 0")
        if not (type(self.N) is int and self.N >= 1):
            raise ParameterError(f"parameter N = {self.N!r} is not allowed: must be a "
                                 "positive integer")

    @property
    def h(self) -> float:
        """The base step ``T / N``."""
        return self.T / self.N

    def ticks(self, duration: float, name: str = "--stop-time") -> int:
        """Base steps in ``duration`` (> 0, a multiple of ``h``), else ParameterError."""
        try:
            return grid.ticks(duration, self.T, self.N, name)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None

    def check_on_grid(self, name: str, value: float) -> None:
        """Refuse a delay ``value`` that is not a multiple of ``h``."""
        if not grid.on_grid(value, self.h):
            raise ParameterError(
                f"parameter {name} = {value!r} is not allowed: must be a multiple of the "
                f"base step h = T/N = {self.h!r}: {grid.base_alternatives(value, self.T, self.N)}")


@dataclass(frozen=True)
class LtiDesign:
    """What an LTI loop is made of, for exact analyses: ``x' = A x + B u(t - tau)``,
    ``u = K x`` (the paper's sign) on the predicted (``compensated``) or sampled state."""

    A: np.ndarray
    B: np.ndarray
    K: np.ndarray
    r: float
    tau: float
    mode: str
    x0: np.ndarray
    u0: np.ndarray
    r_true: float | None = None
    tau_true: float | None = None
    #: the controller pads ``tau`` up to ``ceil(tau / T) T`` (Remark 3.3(b)): its output
    #: is delayed by the difference (``equivalent`` gives the loop it equals)
    pad: bool = False

    def equivalent(self, T: float) -> LtiDesign:
        """The unpadded design of the same loop: a padded controller (``pad``) predicts over
        ``tau_eff = ceil(tau / T) T`` and delays its output by ``tau_eff - tau``, so the
        plant sees ``u(t - tau_eff)``: the loop of ``tau = tau_eff`` and a true input delay
        longer by the padding (the plant's state the same; the controller's output column
        earlier by the padding). Without ``pad``, the design itself.

        >>> d = LtiDesign(*[np.eye(1)] * 3, 0.0, 0.7, "compensated", np.zeros(1),
        ...               np.zeros(1), pad=True)
        >>> e = d.equivalent(0.5)
        >>> e.tau, e.tau_true, e.pad
        (1.0, 1.0, False)
        """
        if not self.pad:
            return self
        tau_eff = grid.padded_delay(self.tau, T)
        true = self.tau if self.tau_true is None else self.tau_true
        return dataclasses.replace(self, tau=tau_eff, tau_true=true + (tau_eff - self.tau),
                                   pad=False)

    @property
    def n(self) -> int:
        """The number of states."""
        return self.B.shape[0]

    @property
    def m(self) -> int:
        """The number of inputs."""
        return self.B.shape[1]


@dataclass(frozen=True)
class Origin:
    """What a loop was built from, as a loop file says it: the loop-file ``data`` (a dict
    as the TOML reads: top-level keys, ``plant`` and ``controller`` tables) and the folder
    ``base`` its relative paths resolve against. A loop that keeps its origin can be built
    again with overrides (a sweep's grid points, ``sets``):
    ``LoopData``."""

    data: Mapping[str, Any]
    base: Path | None = None


@dataclass(frozen=True)
class Loop:
    """A closed loop ready for a master; validated when built (see module docstring)."""

    instances: tuple[Instance, ...]
    connections: tuple[Connection, ...]
    timing: Timing
    recorded: tuple[Port, ...] = ()
    #: a name for files and titles (scenario name or loop file stem); like the title, the
    #: default stop time and the LTI design, it does not take part in comparing loops
    name: str = field(default="loop", compare=False)
    title: str = field(default="", compare=False)
    stop_time: float | None = field(default=None, compare=False)
    lti: LtiDesign | None = field(default=None, compare=False)
    #: the values some outputs must have once the instances are initialized, each a
    #: ``(port, value)``: a plant FMU's measured outputs and ``x0``, the history the loop
    #: assumes (the master refuses to run a loop whose plant starts elsewhere)
    initial: tuple[tuple[Port, float], ...] = ()
    #: the column names of some recorded ports, each a ``(port, name)``, where the port's
    #: own ``instance.variable`` is not what the column shows (a plant FMU's input, recorded
    #: as the input delay's output that drives it, is ``plant.<the FMU's input name>``)
    labels: tuple[tuple[Port, str], ...] = ()
    #: the loop-file data it was built from (``Origin``; set by the loop-file reader,
    #: ``api.lti`` and ``api.model``), for building it again with overrides; ``None`` for a
    #: loop put together otherwise
    origin: Origin | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "instances", tuple(self.instances))
        object.__setattr__(self, "initial", tuple((p, float(v)) for p, v in self.initial))
        object.__setattr__(self, "labels", tuple((p, str(n)) for p, n in self.labels))
        object.__setattr__(self, "connections", tuple(self.connections))
        object.__setattr__(self, "recorded", tuple(self.recorded))
        names = [i.name for i in self.instances]
        if len(set(names)) != len(names):
            raise ParameterError(f"loop {self.name}: instance names must be distinct: {names}")
        for port, label in self.labels:
            if port not in self.recorded:
                raise ParameterError(f"loop {self.name}: label {label!r} names {port}, which "
                                     "is not recorded")
        columns = self.columns if self.labels else []
        if len(set(columns)) != len(columns):
            dup = next(c for c in columns if columns.count(c) > 1)
            raise ParameterError(f"loop {self.name}: two recorded columns are named {dup!r}")
        for inst in self.instances:
            if inst.role not in ROLES:
                raise ParameterError(f"loop {self.name}: instance {inst.name} has role "
                                     f"{inst.role!r}: allowed are {', '.join(ROLES)}")
        roles = [i.role for i in self.instances]
        for role in ROLES:
            if roles.count(role) > 1:
                raise ParameterError(f"loop {self.name}: more than one {role}")
        for port in [p for c in self.connections for p in (c.src, c.dst)] + list(
                self.recorded) + [p for p, _ in self.initial]:
            if port.instance not in names:
                raise ParameterError(f"loop {self.name}: {port} names no instance: "
                                     f"allowed are {', '.join(names)}")

    def __repr__(self) -> str:
        """A short form (the fields' full ``repr`` runs to kilobytes): the name, the
        measured states ``n`` and inputs ``m``, the timing.

        >>> lti_loop([[1.0]], [[1.0]], [[-2.0]], T=1.0, r=0.3, tau=0.0, N=100,
        ...          mode="compensated", x0=[1.0], u0=[0.0], name="ex")
        <Loop 'ex' n=1 m=1 T=1 N=100>
        """
        plant, ctrl = self.by_role("plant"), self.by_role("controller")
        n = sum(1 for p in self.recorded if plant is not None and p.instance == plant.name)
        m = sum(1 for p in self.recorded if ctrl is not None and p.instance == ctrl.name)
        return f"<Loop {self.name!r} n={n} m={m} T={self.T:.6g} N={self.N}>"

    # -- reading --
    @property
    def T(self) -> float:
        """The sampling period."""
        return self.timing.T

    @property
    def N(self) -> int:
        """Base steps per sampling period."""
        return self.timing.N

    @property
    def h(self) -> float:
        """The base step ``T / N``."""
        return self.timing.h

    @property
    def names(self) -> list[str]:
        """The instances' names, in the loop's order."""
        return [i.name for i in self.instances]

    def instance(self, name: str) -> Instance:
        """The instance called ``name`` (``KeyError`` naming the loop if there is none)."""
        for inst in self.instances:
            if inst.name == name:
                return inst
        raise KeyError(f"loop {self.name}: no instance {name!r}")

    def column(self, port: Port) -> str:
        """The column name of the recorded ``port``: its label (``labels``), else
        ``instance.variable``."""
        return dict(self.labels).get(port, str(port))

    @property
    def columns(self) -> list[str]:
        """The column names of the recorded ports, in order (``column``)."""
        return [self.column(p) for p in self.recorded]

    def by_role(self, role: Role) -> Instance | None:
        """The instance with ``role``, or ``None``."""
        for inst in self.instances:
            if inst.role == role:
                return inst
        return None

    def parameters(self) -> dict[str, dict]:
        """Instance name -> its parameter values (what the master sets before
        initialization)."""
        return {i.name: dict(i.parameters) for i in self.instances}

    # -- rewriting --
    def replace(self, **changes) -> Loop:
        """A copy with fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def with_instances(self, instances: Iterable[Instance]) -> Loop:
        """A copy with these instances."""
        return self.replace(instances=tuple(instances))

    def set_parameters(self, name: str, **changes) -> Loop:
        """A copy with parameters of instance ``name`` changed."""
        return self.with_instances(i.with_parameters(**changes) if i.name == name else i
                                   for i in self.instances)


# -- network channels ------------------------------------------------------------------

def channel_roles(loop: Loop) -> list[str]:
    """The roles of ``loop`` (``meas_delay``, ``input_delay``) that a network channel
    fills."""
    return [i.role for i in loop.instances
            if isinstance(i.source, BuiltinFmu) and i.source.kind == "channel"]


def refuse_channel(loop: Loop, what: str) -> None:
    """Refuse (``ParameterError``, one line) a ``loop`` with a network channel where
    ``what`` (a command, an engine) does not handle one yet."""
    roles = channel_roles(loop)
    if roles:
        raise ParameterError(f"loop {loop.name!r}: the [{roles[0]}] channel is not supported "
                             f"by {what} yet")


# -- the standard loop ---------------------------------------------------------------------

def standard_wiring(plant_out: list[str], ctrl_in: list[str], ctrl_out: list[str],
                    plant_in: list[str]) -> tuple[Connection, ...]:
    """The standard loop's connections: plant -> meas_delay -> controller -> input_delay
    -> plant, channel by channel (a delay's ports ``u``, ``y``, numbered ``u1``, ``y1``,
    ... where it carries several), whatever the plant and the controller are (built in, a
    model file's, an FMU file).

    Examples
    --------
    >>> for c in standard_wiring(["x1", "x2"], ["y1", "y2"], ["u"], ["force"]):
    ...     print(c)
    plant.x1 -> meas_delay.u1
    plant.x2 -> meas_delay.u2
    meas_delay.y1 -> controller.y1
    meas_delay.y2 -> controller.y2
    controller.u -> input_delay.u
    input_delay.y -> plant.force
    """
    n, m = len(plant_out), len(plant_in)
    ys_in, ys_out = indexed("u", n), indexed("y", n)
    dl_in, dl_out = indexed("u", m), indexed("y", m)

    def c(a, av, b, bv):
        return Connection(Port(a, av), Port(b, bv))

    return tuple(
        [c("plant", x, "meas_delay", i) for x, i in zip(plant_out, ys_in)]
        + [c("meas_delay", o, "controller", i) for o, i in zip(ys_out, ctrl_in)]
        + [c("controller", u, "input_delay", i) for u, i in zip(ctrl_out, dl_in)]
        + [c("input_delay", o, "plant", u) for o, u in zip(dl_out, plant_in)])


def vector_params(label: str, v) -> dict:
    """The FMU parameters of vector ``v``: ``{"label[1]": v[0], ...}``."""
    return {f"{label}[{i + 1}]": float(x) for i, x in enumerate(v)}


def matrix_params(label: str, M) -> dict:
    """The FMU parameters of matrix ``M``: ``{"label[1,1]": M[0, 0], ...}`` (row by row)."""
    return {f"{label}[{i + 1},{j + 1}]": float(M[i, j])
            for i in range(M.shape[0]) for j in range(M.shape[1])}


def check_delays(timing: Timing, r: float, tau: float, r_true, tau_true,
                 zoh: Literal["hold", "pad"] | None = None) -> tuple[float, float]:
    """The true delays ``(r_true, tau_true)`` (each the assumed one where ``None``), after
    refusing any delay that is not a finite number >= 0 on the base grid.

    ``zoh``: the controller holds its output over each period, so ``tau`` must be a
    multiple of ``T`` (``check_zoh_delay``; ``"pad"``: the caller could pad it). That
    rule is checked before the base grid's: a multiple of ``T`` is on the grid of every
    ``N``, and a ``tau`` off both is refused with the fix of the rule that binds (the
    nearest multiples of ``T``, ``pad``), never with the base grid's."""
    for name, value in (("r", r), ("tau", tau), ("r_true", r_true), ("tau_true", tau_true)):
        if value is None and name in ("r_true", "tau_true"):  # default: the assumed one
            continue
        if not (isinstance(value, numbers.Real) and math.isfinite(value)
                and float(value) >= 0):
            raise ParameterError(f"parameter {name} = {value!r} is not allowed: must be a "
                                 "finite number >= 0")
        if name == "tau" and zoh is not None:
            check_zoh_delay(cast(float, value), timing.T, padding=zoh == "pad")
        timing.check_on_grid(name, cast(float, value))
    return (r if r_true is None else r_true), (tau if tau_true is None else tau_true)


def check_zoh_delay(tau: float, T: float, padding: bool = False) -> None:
    """Under zero-order hold the input delay is a whole number of periods, ``tau = l T``
    (``delaycomp.maths.grid.periods``, the rule written once), as a
    ``ParameterError``. The loop builders call it where ``tau``
    enters a loop whose controller holds its output over each period (the LTI controller;
    a model with ``control = "zoh"`` unless it pads); ``padding``: the message says what
    ``pad = true`` gives."""
    try:
        grid.periods(tau, T, "parameter tau", padding, hints=True)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None


@dataclass(frozen=True)
class LtiPoint:
    """An LTI loop's design and timing without its instances: what a batch sweep needs of
    a grid point (``delaycomp.paper.scenarios.Scenario.design``). It carries the same
    ``lti`` and ``timing`` fields as the ``Loop`` that ``design_loop`` builds from
    it, validated by the same code (``lti_design``)."""

    lti: LtiDesign
    timing: Timing


def lti_design(A, B, K, T: float, r: float, tau: float, N: int, mode: str, x0, u0,
               r_true: float | None = None, tau_true: float | None = None,
               pad: bool = False) -> LtiPoint:
    """The validated design and timing of the LTI loop ``lti_loop`` builds.

    Every check of ``lti_loop`` happens here (shapes, finite entries, histories, mode,
    the base grid of the delays, ``tau = l T`` unless ``pad``), so a point that passes
    builds a valid loop.

    Examples
    --------
    >>> pt = lti_design([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.3, 0.0, 100, "compensated",
    ...                 [1.0], [0.0])
    >>> pt.lti.K, pt.timing.h
    (array([[-2.]]), 0.01)
    >>> lti_design([[1.0]], [[1.0]], [[-2.0]], 1.0, 0.305, 0.0, 100, "compensated",
    ...            [1.0], [0.0])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: parameter r = 0.305 is not allowed: must be a multiple ...
    """
    A, B, K = (np.atleast_2d(_floats(f"matrix {label}", M))
               for label, M in (("A", A), ("B", B), ("K", K)))
    n = A.shape[0]
    if A.ndim != 2 or A.shape != (n, n):
        raise ParameterError(f"matrix A has shape {A.shape}: must be square (n x n)")
    if B.ndim != 2 or B.shape[0] != n:
        raise ParameterError(f"matrix B has shape {B.shape}: must have n = {n} rows")
    m = B.shape[1]
    if K.shape != (m, n):
        raise ParameterError(f"matrix K has shape {K.shape}: must be m x n = {m} x {n} "
                             "(u = K x)")
    for label, M in (("A", A), ("B", B), ("K", K)):
        if not np.isfinite(M).all():
            raise ParameterError(f"matrix {label} has entries that are not finite numbers")
    x0 = _floats("parameter x0", x0).ravel()
    u0 = _floats("parameter u0", u0).ravel()
    if x0.shape != (n,):
        raise ParameterError(f"parameter x0 has {x0.size} values: must have n = {n}")
    if u0.shape != (m,):
        raise ParameterError(f"parameter u0 has {u0.size} values: must have m = {m}")
    if mode not in MODES:
        raise ParameterError(f"parameter mode = {mode!r} is not allowed: must be "
                             f"{' or '.join(MODES)}")
    timing = Timing(T, N)
    check_delays(timing, r, tau, r_true, tau_true, zoh=None if pad else "pad")
    return LtiPoint(LtiDesign(A, B, K, r, tau, mode, x0, u0, r_true, tau_true,
                              bool(pad)), timing)


@dataclass(frozen=True)
class LtiBatch:
    """Many LTI grid points at once, as arrays with a leading axis of points: what
    ``lti_designs`` validated (the fields of ``LtiPoint``, stacked). ``r_true``
    and ``tau_true`` are filled in with ``r`` and ``tau`` where a point has none."""

    A: np.ndarray  # (P, n, n)
    B: np.ndarray  # (P, n, m)
    K: np.ndarray  # (P, m, n)
    T: np.ndarray  # (P,)
    N: np.ndarray  # (P,) int64
    r: np.ndarray
    tau: np.ndarray
    r_true: np.ndarray
    tau_true: np.ndarray
    x0: np.ndarray  # (P, n)
    u0: np.ndarray  # (P, m)
    mode: np.ndarray  # (P,) of str

    def __len__(self) -> int:
        return len(self.T)

    def timings(self) -> set[Timing]:
        """The distinct timings of the points."""
        pairs = set(zip(self.T.tolist(), self.N.tolist()))
        return {Timing(T, N) for T, N in pairs}


def lti_designs(args: list[dict]) -> LtiBatch | None:
    """``lti_design`` for many points at once (each dict holds one point's arguments),
    its checks vectorized: a grid sweep validates every point without a loop of numpy calls
    per point.

    Returns ``None`` where the points do not stack (matrices of different shapes, an
    argument that is not an array of numbers) or some point fails a check: validate those
    one by one with ``lti_design``, which names what is wrong with the first failing
    point. A batch it returns holds only points ``lti_design`` accepts.

    Examples
    --------
    >>> pts = [dict(A=[[1.0]], B=[[1.0]], K=[[-k]], T=1.0, r=r, tau=0.0, N=100,
    ...             mode="compensated", x0=[1.0], u0=[0.0]) for k in (1, 2) for r in (0, .5)]
    >>> batch = lti_designs(pts)
    >>> len(batch), batch.K[:, 0, 0].tolist(), batch.r_true.tolist()
    (4, [-1.0, -1.0, -2.0, -2.0], [0.0, 0.5, 0.0, 0.5])
    >>> lti_designs([*pts, {**pts[0], "r": 0.305}]) is None  # off the base grid
    True
    """
    if not args or any(a.get("pad") for a in args):  # a padded point: one by one
        return None
    stacked = _stacked_arrays(args)
    if stacked is None:
        return None
    T = [a["T"] for a in args]
    Ns = [a["N"] for a in args]
    delays = {key: [a.get(key) for a in args] for key in ("r", "tau", "r_true", "tau_true")}
    if not (all(isinstance(v, (int, float)) for v in T)
            and all(type(v) is int for v in Ns)
            and all(isinstance(v, (int, float)) for key in ("r", "tau") for v in delays[key])
            and all(v is None or isinstance(v, (int, float))
                    for key in ("r_true", "tau_true") for v in delays[key])):
        return None
    batch = _checked_batch(args, *stacked, T, Ns, delays)
    if batch is None:
        return None
    try:  # zero-order hold: tau = l T at every point (each distinct pair once)
        for tau_p, T_p in set(zip(batch.tau.tolist(), batch.T.tolist())):
            grid.periods(tau_p, T_p)
    except ValueError:
        return None
    return batch


def _stacked_arrays(args: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                np.ndarray, np.ndarray] | None:
    """A, B, K (3-d), x0 and u0 (2-d) of the points stacked; None where they do not stack."""
    try:
        A, B, K = (np.array([a[key] for a in args], dtype=float) for key in "ABK")
        x0, u0 = (np.array([np.ravel(a[key]) for a in args], dtype=float)
                  for key in ("x0", "u0"))
    except (TypeError, ValueError):  # ragged, or not numbers: one by one
        return None
    if A.ndim != 3 or B.ndim != 3 or K.ndim != 3 or x0.ndim != 2 or u0.ndim != 2:
        return None
    return A, B, K, x0, u0


def _checked_batch(args: list[dict], A: np.ndarray, B: np.ndarray, K: np.ndarray,
                   x0: np.ndarray, u0: np.ndarray, T: list, Ns: list,
                   delays: dict[str, list]) -> LtiBatch | None:
    """The batch of stacked points when the shapes, entries, modes, timings and delays (on
    the base grid) of every point pass ``lti_design``'s checks, else None."""
    _, n, m = B.shape
    T_a, N_a = np.array(T, dtype=float), np.array(Ns, dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):  # a bad T or N: refused below
        h = T_a / N_a
    r, tau = np.array(delays["r"], dtype=float), np.array(delays["tau"], dtype=float)
    r_true = np.array([x if v is None else v for x, v in zip(delays["r"],
                                                             delays["r_true"])], float)
    tau_true = np.array([x if v is None else v for x, v in zip(delays["tau"],
                                                               delays["tau_true"])], float)
    mode = np.array([a["mode"] for a in args], dtype=object)
    if not (A.shape[1:] == (n, n) and K.shape[1:] == (m, n) and x0.shape[1] == n
            and u0.shape[1] == m and np.isfinite(A).all() and np.isfinite(B).all()
            and np.isfinite(K).all() and all(isinstance(md, str) and md in MODES
                                             for md in mode.tolist())
            and bool(np.all(np.isfinite(T_a) & (T_a > 0))) and bool(np.all(N_a >= 1))):
        return None
    for d in (r, tau, r_true, tau_true):
        if not bool(np.all(np.isfinite(d) & (d >= 0) & grid.on_grid_array(d, h))):
            return None
    return LtiBatch(A, B, K, T_a, N_a, r, tau, r_true, tau_true, x0, u0, mode)


def _floats(what: str, value) -> np.ndarray:
    """``value`` as an array of floats, or a one-line ParameterError naming ``what``."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{what} = {value!r} is not allowed: must be numbers") from None


def design_loop(point: LtiPoint, state: str = "x", inp: str = "u", name: str = "loop",
                title: str = "", stop_time: float | None = None,
                origin: Origin | None = None) -> Loop:
    """The standard four-instance loop of a validated ``LtiPoint`` (``origin``: what
    it was built from, ``Loop.origin``)."""
    d, timing = point.lti, point.timing
    A, B, K, x0, u0 = d.A, d.B, d.K, d.x0, d.u0
    n, m = d.n, d.m
    r_loop = d.r if d.r_true is None else d.r_true
    tau_loop = d.tau if d.tau_true is None else d.tau_true
    xs, us = indexed(state, n), indexed(inp, m)
    instances = (
        Instance("plant", "plant",
                 BuiltinFmu("plant", {"n": n, "m": m, "state": state, "input": inp}),
                 {**matrix_params("A", A), **matrix_params("B", B), **vector_params("x0", x0)}),
        Instance("meas_delay", "meas_delay", BuiltinFmu("delay", {"n": n}),
                 {"delay": r_loop, **vector_params("u0", x0)}),
        Instance("controller", "controller", BuiltinFmu("controller", {"n": n, "m": m}),
                 {"T": timing.T, "r": d.r, "tau": d.tau, "mode": d.mode, **matrix_params("A", A),
                  **matrix_params("B", B), **matrix_params("K", K), **vector_params("u0", u0),
                  **({"pad": True} if d.pad else {})}),
        Instance("input_delay", "input_delay", BuiltinFmu("delay", {"n": m}),
                 {"delay": tau_loop, **vector_params("u0", u0)}),
    )
    recorded = tuple([Port("plant", x) for x in xs] + [Port("controller", u) for u in us])
    return Loop(instances, standard_wiring(xs, indexed("y", n), us, us), timing, recorded, name,
                title, stop_time, d, origin=origin)


def lti_loop(A, B, K, T: float, r: float, tau: float, N: int, mode: str, x0, u0,
             state: str = "x", inp: str = "u", r_true: float | None = None,
             tau_true: float | None = None, name: str = "loop", title: str = "",
             stop_time: float | None = None, pad: bool = False) -> Loop:
    """Plant, measurement delay r, ZOH controller and input delay tau around an LTI plant.

    ``plant.x -> meas_delay -> controller -> input_delay -> plant.u``, with ``u = K x``
    (the paper's sign). The history of x on ``[-r, 0]`` is the constant ``x0`` (the
    measurement delay's initial history), the controller's output history on
    ``[-r - tau, 0)`` the constant ``u0``. The delay FMUs apply the loop's true delays
    ``r_true``, ``tau_true`` (default: the assumed ``r``, ``tau``). ``pad``: a ``tau``
    that is no multiple of ``T`` is padded up to the next one by the controller (Remark
    3.3(b)). The same as ``design_loop(lti_design(...))``.
    """
    return design_loop(lti_design(A, B, K, T, r, tau, N, mode, x0, u0, r_true, tau_true,
                                  pad), state, inp, name, title, stop_time)


def check_model_loop(model, T: float, r: float, tau: float, N: int, x0, u0,
                     params: dict | None = None, pad: bool = False,
                     r_true: float | None = None, tau_true: float | None = None) -> tuple:
    """The checks of ``model_loop`` for a loaded ``model`` (``delaycomp.maths.model``),
    without building the loop: the lengths of ``x0`` and ``u0``, the parameter names, the
    delays on the base grid and, under zero-order hold unless ``pad``, ``tau = l T``.

    Returns ``(x0, u0, params, timing, r_true, tau_true)``: the histories as lists of
    floats, the parameters as a new dict, the ``Timing`` and the true delays.
    """
    n, m = model.n, model.m
    x0 = [float(v) for v in np.ravel(x0)]
    u0 = [float(v) for v in np.ravel(u0)]
    if len(x0) != n:
        raise ParameterError(f"parameter x0 has {len(x0)} values: must have {n} "
                             f"({', '.join(model.states)})")
    if len(u0) != m:
        raise ParameterError(f"parameter u0 has {len(u0)} values: must have {m} "
                             f"({', '.join(model.inputs)})")
    params = dict(params or {})
    unknown = [k for k in params if k not in model.parameters]
    if unknown:
        allowed = ", ".join(model.parameters) or "none"
        raise ParameterError(f"model {model.name} has no parameter {unknown[0]!r}: allowed "
                             f"are {allowed}")
    timing = Timing(T, N)
    r_loop, tau_loop = check_delays(timing, r, tau, r_true, tau_true,
                                    zoh="pad" if model.control == "zoh" and not pad else None)
    return x0, u0, params, timing, r_loop, tau_loop


def model_loop(model_path, T: float, r: float, tau: float, N: int, x0, u0, z0=None,
               params: dict | None = None, mode: str | None = None,
               predictor: str | None = None, tolerance: float | None = None,
               pad: bool = False, r_true: float | None = None,
               tau_true: float | None = None, name: str = "loop", title: str = "",
               stop_time: float | None = None) -> Loop:
    """Plant, delays and predictor-controller around a model file (``delaycomp.maths.model``).

    Column names are the model's own: ``plant.<state>`` and ``controller.<input>``.
    ``params`` are the model's parameters (an unknown name is refused).
    """
    from delaycomp.maths.model import load_model

    model = load_model(model_path)
    x0, u0, params, timing, r_loop, tau_loop = check_model_loop(
        model, T, r, tau, N, x0, u0, params, pad, r_true, tau_true)
    n, m = model.n, model.m
    path = Path(model_path)
    ctrl = {"T": T, "r": r, "tau": tau, "N": N, "pad": bool(pad), **vector_params("u0", u0),
            **vector_params("z0", x0 if z0 is None else z0), **params}
    if mode is not None:
        ctrl["mode"] = mode
    if predictor is not None:
        ctrl["predictor"] = predictor
    plant = {**vector_params("x0", x0), **params}
    if tolerance is not None:
        plant["tolerance"] = ctrl["tolerance"] = tolerance
    instances = (
        Instance("plant", "plant", ModelFmu("model_plant", path), plant),
        Instance("meas_delay", "meas_delay", BuiltinFmu("delay", {"n": n}),
                 {"delay": r_loop, **vector_params("u0", x0)}),
        Instance("controller", "controller", ModelFmu("model_controller", path), ctrl),
        Instance("input_delay", "input_delay", BuiltinFmu("delay", {"n": m}),
                 {"delay": tau_loop, **vector_params("u0", u0)}),
    )
    recorded = tuple([Port("plant", s) for s in model.states]
                     + [Port("controller", u) for u in model.inputs])
    connections = standard_wiring(list(model.states), [f"y_{s}" for s in model.states],
                                  list(model.inputs), list(model.inputs))
    return Loop(instances, connections, timing, recorded, name, title, stop_time)
