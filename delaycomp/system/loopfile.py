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

import re
from pathlib import Path
from typing import Any

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser, as the tomli package
    import tomli as tomllib

from delaycomp.errors import BadFileError, ParameterError, shown
from delaycomp.maths.grid import on_grid
from delaycomp.system.loop import (
    Loop,
    LtiBatch,
    LtiPoint,
    Origin,
    check_model_loop,
    design_loop,
    lti_design,
    lti_designs,
    model_loop,
)
from delaycomp.system.loopchannels import TRACE_MAX as TRACE_MAX  # importable here as before
from delaycomp.system.loopchannels import (
    channel_of,
    check_stamped_model,
    refuse_channel_data,
    with_channels,
    with_stamps,
)
from delaycomp.system.loopchannels import channel_parameters as channel_parameters
from delaycomp.system.loopchannels import read_trace as read_trace
from delaycomp.system.loopkeys import CHANNEL_TABLES, DEFAULTS, allowed
from delaycomp.system.loopkeys import ON_BASE_GRID as ON_BASE_GRID  # importable here as before
from delaycomp.system.loopkeys import ZOH_TAU as ZOH_TAU
from delaycomp.system.loopkeys import ZOH_TAU_PAD as ZOH_TAU_PAD
from delaycomp.system.loopplantfmu import fmu_plant, fmu_tolerance
from delaycomp.system.loopvalues import KEYS as KEYS  # importable here as before
from delaycomp.system.loopvalues import (
    NESTED,
    array_value,
    check_keys,
    check_sign,
    check_value,
    flag_value,
    model_value,
    parse_value,
    real_value,
)
from delaycomp.system.loopvalues import Key as Key
from delaycomp.system.loopvalues import SignError as SignError

#: the keys of each table, required or not, and the defaults: ``.loopkeys``
TOP_KEYS = allowed("", "lti")
SECTIONS = ("plant", "controller")
#: tables that describe something besides the loop (``[reference]``: for ``check``)
OTHER_TABLES = ("reference",)
DEFAULT_N: int = int(DEFAULTS["N"])  # type: ignore[call-overload]

# -- the file ------------------------------------------------------------------------------

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
        return None if stop is None else real_value("stop_time", stop, positive=True)

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
                check_keys(self.where, {name: 0}, TOP_KEYS)
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
    check_keys(where, {k: v for k, v in data.items() if k not in SECTIONS}, TOP_KEYS,
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


def _lti_args(top: dict, where: str, array=array_value) -> tuple[dict, tuple[str, str], bool]:
    """The ``lti_design`` arguments of an LTI loop file
    (``[plant] A, B``), its state and input names, and whether the sign guard applies;
    the keys and values checked as ``build`` checks them (``array`` parses a list)."""
    plant, ctrl = top["plant"], top["ctrl"]
    x0 = array("plant.x0", plant["x0"], 1)
    check_keys(f"{where} [plant]", plant, allowed("plant", "lti"))
    check_keys(f"{where} [controller]", ctrl, allowed("controller", "lti"))
    if "B" not in plant or "K" not in ctrl:
        raise ParameterError(f"{where}: an LTI loop needs plant.B and controller.K")
    A = array("plant.A", plant["A"], 2)
    B = array("plant.B", plant["B"], 2)
    K = array("controller.K", ctrl["K"], 2)
    u0 = array("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else np.zeros(B.shape[1])
    names = (_ident("plant.state", plant.get("state", DEFAULTS["plant.state"])),
             _ident("plant.input", plant.get("input", DEFAULTS["plant.input"])))
    guard = not flag_value("controller.allow_unstable",
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
            hit = parsed[key] = (value, array_value(what, value, ndim))
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


#: the loop's true delay that each channel table's ``delay`` defaults to
_TRUE = {"meas_delay": "r", "input_delay": "tau"}


def _true_delay(top: dict, table: str) -> float:
    """The loop's true delay of ``table``'s role: ``r_true`` (else ``r``) or ``tau_true``
    (else ``tau``)."""
    name = _TRUE[table]
    true = top[f"{name}_true"]
    return float(top[name] if true is None else true)


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
        loop = fmu_tolerance(plant, lambda: fmu_plant(plant, ctrl, base, where, T, N, r,
                                                      tau, mode, common))
    elif "A" in plant:
        point, state, inp = _lti(top, where)
        loop = design_loop(point, state, inp, name=name, title=title, stop_time=stop)
    else:
        model_path, _, args = _model_args(top, base, where)
        loop = model_loop(model_path, T, r, tau, N, **args, **common)
    loop = with_stamps(with_channels(loop, data, base, where), data, where)
    return loop.replace(origin=origin)


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
    check_keys(f"{where} [plant]", plant, allowed("plant", "model"))
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
    tol = None if tol is None else real_value("tolerance", tol, positive=True)
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
            check_stamped_model(path, where)
        check_model_loop(model, top["T"], top["r"], top["tau"], top["N"], args["x0"],
                         args["u0"], args["params"], args["pad"], top["r_true"],
                         top["tau_true"])


def _ident(where: str, value) -> str:
    if not (isinstance(value, str) and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", value)):
        raise ParameterError(f"{where} = {value!r} is not allowed: must be an identifier")
    return value


def read_loop(path: str | Path, assignments: list[str] | dict | None = None) -> Loop:
    """The loop of the file at ``path`` with ``NAME=VALUE`` overrides."""
    return LoopFile(path).loop(assignments)
