"""``delaycomp export-c``: a loop's controller as plain C for an embedded target.

The controller of a loop (an LTI loop's, or a model file's, either family) is written as
``DIR/NAME.h`` and ``DIR/NAME.c``: C99, no heap, no I/O, no global state (everything lives
in ``NAME_state``, a struct of fixed size; two controllers live in one program), with this
interface::

    void NAME_init(NAME_state *s);
    int  NAME_sample(NAME_state *s, double t, const double *y);
    int  NAME_output(NAME_state *s, double t, double *u);

The maths is the native controller FMU's (``fmus/controller/controller_lti.c``,
``model_controller.c``) without its FMI layer; the loop's parameters are constants of
``NAME.c``. An LTI controller's matrices ``e^{A (r + tau)}`` and ``Q_p B`` are computed
here, once (``delaycomp.maths.lti.LTIPredictor``); a model's ``f``, ``k`` and ``step`` are
its C from ``delaycomp.fmu.translate``, and the numerical predictor's integrator is
``fmus/native/ode.c`` (DOP853), put into ``NAME.c`` with ``static`` linkage. The values are
checked by the controller FMU's own code (its Python twin, in-process), so a bad value is
refused with the FMU's message. The C templates are ``fmus/native/export/``.
"""
from __future__ import annotations

import importlib.util
import re
import textwrap
from pathlib import Path

import numpy as np

from delaycomp.errors import ParameterError
from delaycomp.maths.grid import GRID_RTOL
from delaycomp.maths.model import ModelError
from delaycomp.maths.nlcontrol import PREDICTORS as _PREDICTOR_NAMES
from delaycomp.maths.predictors import MAX_ODE_STEPS
from delaycomp.tmpfiles import write_text

__all__ = ["EXPORT_CODES", "check_prefix", "closed_loop_io", "export_c"]

#: the return codes of NAME_sample and NAME_output (NAME_OK = 0), as the header states them
EXPORT_CODES = {
    "OK": (0, "accepted"),
    "E_NOT_FINITE": (1, "t or a value of y is not finite"),
    "E_OFF_GRID": (2, "t is not on the base grid t0 + k h (NAME_sample: not a sample "
                      "instant t0 + i T)"),
    "E_ORDER": (3, "t is not the next base time (NAME_output) or the next sample instant "
                   "(NAME_sample), or NAME_output before the first NAME_sample"),
    "E_NO_SAMPLE": (4, "NAME_output at a sample instant whose NAME_sample was not called"),
    "E_DIVERGED": (5, "the control is not finite (the predictor or the feedback "
                      "overflowed)"),
    "E_SOLVER": (6, "the model's flow failed: an ODE solve did not converge within "
                    "NAME_MAX_ODE_STEPS steps, or the model's f or step failed"),
}

_PREFIX = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,39}")
_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto "
    "if inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while".split())
#: the standard headers of C (C99; C11's and C23's added) and the top-level headers of POSIX
#: (IEEE Std 1003.1-2024): ``NAME.h`` of one of these names in the output folder shadows
#: the system's header for every file compiled with that folder on its include path
#: (``--prefix math``: ``sqrt`` undeclared); compared in any case (macOS's and Windows'
#: file systems are case-insensitive: ``Math.h`` shadows ``math.h`` there)
_HEADERS = frozenset(
    # C99
    "assert complex ctype errno fenv float inttypes iso646 limits locale math setjmp signal "
    "stdarg stdbool stddef stdint stdio stdlib string tgmath time wchar wctype "
    # C11, C23
    "stdalign stdatomic stdnoreturn threads uchar stdbit stdckdint "
    # POSIX, beyond C's (the ones in subfolders, sys/... and the like, cannot be shadowed)
    "aio cpio devctl dirent dlfcn endian fcntl fmtmsg fnmatch ftw glob grp iconv langinfo "
    "libgen libintl monetary mqueue ndbm netdb nl_types poll pthread pwd regex sched search "
    "semaphore spawn strings stropts syslog tar termios trace ulimit unistd utime utmpx "
    "wordexp".split())
#: file names Windows reserves for devices, whatever their extension and case: ``CON.h``
#: cannot be written there
_WINDOWS_RESERVED = frozenset(["con", "prn", "aux", "nul", *(f"com{i}" for i in range(10)),
                               *(f"lpt{i}" for i in range(10))])
#: DOP853's work memory, doubles per state (ode_work_size of fmus/native/ode.c)
_ODE_WORK_PER_STATE = 17
#: the predictor's number in the C (model.c.in's PREDICT), in the order of
#: delaycomp.maths.nlcontrol.PREDICTORS
PREDICTORS = {name: i for i, name in enumerate(_PREDICTOR_NAMES)}


def _templates() -> Path:
    from delaycomp.fmu.native import SOURCE_DIR

    return SOURCE_DIR


def _c(v: float) -> str:
    """A double as C reads it back exactly (repr is the shortest exact decimal)."""
    v = float(v)
    if not np.isfinite(v):
        raise ParameterError(f"value {v!r} is not allowed in the exported controller: must "
                             "be finite")
    text = repr(v)
    return text if ("." in text or "e" in text) else text + ".0"


def _array(values) -> str:
    flat = [_c(v) for v in np.asarray(values, dtype=float).ravel()]
    lines, line = [], []
    for item in flat:
        line.append(item)
        if len(line) == 4:
            lines.append(", ".join(line))
            line = []
    if line:
        lines.append(", ".join(line))
    return "\n    " + ",\n    ".join(lines) + "\n" if lines else "0.0"


def check_prefix(prefix: str) -> str:
    """The C prefix of the exported names and files, or ``ParameterError`` naming the rule.

    A C identifier (at most 40 characters, not a keyword) whose files ``prefix.h`` and
    ``prefix.c`` break nothing where they are used: not the name of a C or POSIX header
    (``math.h`` in the output folder shadows ``<math.h>``), not ``main`` (the user's
    program's own file), not a device name Windows reserves (``CON``, ``NUL``, ``COM1``,
    ...); each in any case (case-insensitive file systems).

    Examples
    --------
    >>> check_prefix("ctl")
    'ctl'
    >>> check_prefix("Math")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: --prefix 'Math' is not allowed: Math.h would shadow ...
    """
    if not isinstance(prefix, str) or not _PREFIX.fullmatch(prefix) or \
            prefix in _C_KEYWORDS:
        raise ParameterError(f"--prefix {prefix!r} is not allowed: must be a C identifier "
                             "(a letter, then letters, digits or _; at most 40 characters; "
                             "not a C keyword)")
    folded = prefix.lower()
    if folded in _HEADERS:
        raise ParameterError(f"--prefix {prefix!r} is not allowed: {prefix}.h would shadow "
                             f"the system header <{folded}.h> for every file compiled with "
                             "the output folder on its include path (the names of C's and "
                             "POSIX's headers are refused, in any case)")
    if folded == "main":
        raise ParameterError(f"--prefix {prefix!r} is not allowed: {prefix}.c and "
                             f"{prefix}.h would clash with the program's own main file "
                             "(choose a name of the controller, e.g. ctl)")
    if folded in _WINDOWS_RESERVED:
        raise ParameterError(f"--prefix {prefix!r} is not allowed: {prefix} is a device name "
                             "Windows reserves, no file can be called so there (CON, PRN, "
                             "AUX, NUL, COM0 to COM9, LPT0 to LPT9, in any case)")
    return prefix


def _controller(loop):
    """The loop's controller, set up and initialized by the FMU's Python twin (its checks
    and messages): (instance, the slave)."""
    from delaycomp.orchestrator.inprocess import SlaveComponent, SlaveRefused
    from delaycomp.system.loop import FmuFile

    inst = loop.by_role("controller")
    if inst is None:
        raise ParameterError(f"loop {loop.name} has no controller to export")
    if isinstance(inst.source, FmuFile):
        raise ParameterError(f"loop {loop.name}: its controller is the FMU file "
                             f"{inst.source.path}, not one of delaycomp's: nothing to export")
    kind, config = inst.source.build_key()
    if kind not in ("controller", "model_controller"):
        raise ParameterError(f"loop {loop.name}: its controller kind {kind!r} cannot be "
                             "exported (an LTI or a model controller can)")
    comp = SlaveComponent("controller", kind, dict(config))
    try:
        comp.setup(0.0, 1.0, dict(inst.parameters))
        comp.initialize()
    except SlaveRefused as exc:
        raise ParameterError(f"controller: {exc}") from None
    return inst, kind, comp.slave


def _common() -> str:
    """The grid and order checks every exported controller shares (its NAME unfilled)."""
    return (_templates() / "export" / "common.c.in").read_text(encoding="utf-8")


def _fill(template: str, prefix: str, values: dict[str, str]) -> str:
    for key, value in values.items():
        template = template.replace(f"@{key}@", value)
    left = re.findall(r"@[A-Z_]+@", template)
    if left:
        raise AssertionError(f"template placeholders left: {left}")
    return re.sub(r"\bNAME(?=_|\.[ch]\b)", prefix, template)


def _header(prefix: str, loop, dims: dict[str, int], state: str, notes: list[str]) -> str:
    """``NAME.h``: the notes on the loop, the use, the dimensions, the return codes, the
    state's struct and the three functions."""
    from delaycomp.version import __version__
    P = prefix
    codes = "\n".join(
        "\n".join(textwrap.wrap(why.replace("NAME", P), 86, initial_indent="/* ",
                                subsequent_indent=" * ")) + " */\n"
        f"#define {P}_{name} {code}"
        for name, (code, why) in EXPORT_CODES.items())
    dim_lines = "\n".join(f"#define {P}_{k} {v}" for k, v in dims.items())
    what = "\n".join(textwrap.fill(" ".join(notes), 88, initial_indent=" * ",
                                    subsequent_indent=" * ").splitlines())
    return f"""/* {P}.h: the predictor-based controller of loop {loop.name}, exported by
 * `delaycomp export-c` (delaycomp {__version__}). C99; no heap, no I/O, no global state:
 * everything lives in {P}_state, whose size is fixed here, so several controllers (each
 * with its own prefix, or several states of one) live in one program.
 *
{what}
 *
 * Use: {P}_init once; then at every base time t_k = t0 + k h, in order:
 *   - when t_k is a sample instant t0 + i T (every {P}_N base steps, the first call
 *     included: its time is t0), {P}_sample(s, t_k, y) with the measurement that arrived
 *     then, y = x(t_k - r) ({P}_NY values);
 *   - {P}_output(s, t_k, u): the control to apply from t_k to t_k + h ({P}_NU values).
 * Both return {P}_OK (0), or a code below; a refused call changes nothing, so the caller
 * may correct it and call again. Times are checked against the grid up to 1e-9 h and the
 * round-off of t (8 ulps of |t|).
 */
#ifndef {P}_INCLUDED_H
#define {P}_INCLUDED_H

{dim_lines}
#define {P}_T {_c(loop.T)}  /* the sampling period T (s) */
#define {P}_N {loop.N}  /* base steps per sampling period */
#define {P}_H {_c(loop.T / loop.N)}  /* the base step h = T / N (s) */

{codes}

typedef struct {{
{state}
}} {P}_state;

/* The loop file's start values: the held control u0, the stored inputs (all u0), the
 * predictor's state; the parameters are constants of {P}.c. */
void {P}_init({P}_state *s);
/* At a sample instant t = t0 + i T: the measurement that arrived then, y = x(t - r)
 * ({P}_NY values). The first call sets t0. */
int {P}_sample({P}_state *s, double t, const double *y);
/* The control at t ({P}_NU values into u), called at every base-grid time in order, after
 * {P}_sample when t is a sample instant: zero-order hold and continuous input alike. */
int {P}_output({P}_state *s, double t, double *u);

#endif
"""


_COMMON_STATE = """    int started;        /* t0 is set (by the first sample) */
    int sampled;        /* the sample of tick k was taken */
    double t0;          /* the first sample's time */
    long long k;        /* the next base tick, t0 + k h */"""


def _export_lti(prefix, loop, slave) -> tuple[str, str]:
    from delaycomp.maths.grid import steps_of
    from delaycomp.version import __version__
    ctrl = slave.ctrl
    pred = ctrl.predictor
    n, m, L = ctrl.n, ctrl.m, pred.L
    compensated = ctrl.mode == "compensated"
    # pad (Remark 3.3(b)): u_i reaches the output D base steps after t_i (the native
    # controller's pad line: one held value, the output before it; padding < T)
    try:
        D = steps_of(ctrl.padding, loop.h, "padding") if ctrl.padding else 0
    except ValueError as exc:  # tau on the base grid (the loop's check): never here
        raise ParameterError(f"loop {loop.name}: {exc}") from None
    QB = np.hstack(pred.QB)  # n x (m L)
    state = [_COMMON_STATE,
             "    long head;          /* ring position of u_{i-1} in hist */",
             f"    double held[{prefix}_NU];  /* the control held over the period */",
             f"    double pending[{prefix}_NU];  /* u_i from the current sample */",
             f"    double hist[{prefix}_L][{prefix}_NU];  /* u_{{i-1}}, u_{{i-2}}, ..., a "
             "ring */"]
    if D:
        state.append(f"    double pad_line[{prefix}_NU];  /* u_{{i-1}}, the output until "
                     f"t_i + {prefix}_D h */")
    tau = f"tau = {float(slave.tau)!r}"
    if D:
        tau += (f" (padded to {float(ctrl.tau_effective)!r}, Remark 3.3(b): u_i reaches "
                f"the output at t_i + {D} h)")
    notes = [f"Zero-order hold with the LTI predictor (Corollary 3.4): n = {n} states, "
             f"m = {m} inputs,",
             f"T = {loop.T!r}, r = {float(slave.r)!r}, {tau}, mode {ctrl.mode};",
             f"the predictor stores the last L = {L} controls."]
    dims = {"NY": n, "NU": m, "L": L} | ({"D": D} if D else {})
    header = _header(prefix, loop, dims, "\n".join(state), notes)
    template = (_templates() / "export" / "lti.c.in").read_text(encoding="utf-8")
    split = (f"tau_eff = l T = {float(ctrl.tau_effective)!r}, tau = {float(slave.tau)!r} "
             "padded" if D else "tau = l T")
    source = _fill(template, prefix, {
        "LOOP": loop.name, "VERSION": __version__,
        "MATRIX_NOTE": f"n = {n}, m = {m}, L = l + q + 1 = {L} ({split}, r = q T + r~).",
        "GRID_RTOL": repr(GRID_RTOL),
        "COMPENSATED": "1" if compensated else "0",
        "PAD_STEPS": "NAME_D" if D else "0",
        "E": _array(pred.E), "QB": _array(QB), "K": _array(ctrl.K),
        "U0": _array(slave.u0),
        "COMMON": _common()})
    return header, source


def _model_functions(translation, branch: int, names: tuple[str, ...]) -> str:
    """The model's functions of one branch, ``static`` (their names are file-local)."""
    code = []
    for name in names:
        fn = translation.functions[name, branch]
        code.append(re.sub(rf"^int ({name}_{branch}\()", r"static int \1", fn.code,
                           flags=re.M))
    return "\n".join(code)


def _call(translation, name: str, branch: int, values: dict[str, str], out: str = "out") -> str:
    """The call of the model's function ``name`` (of one branch) with its C arguments."""
    fn = translation.functions[name, branch]
    return f"{name}_{branch}({', '.join(values[a] for a in fn.args)}, {out})"


def _export_model(prefix, loop, slave) -> tuple[str, str]:
    from delaycomp.fmu.native import check_closed_form
    from delaycomp.fmu.translate import translate
    from delaycomp.maths.nlcontrol import ZOHModelController
    from delaycomp.version import __version__

    ctrl = slave.ctrl
    model = slave.model
    if importlib.util.find_spec("casadi") is None:
        raise ModelError(f"exporting the controller of model {model.name} translates its f, "
                         "k and step to C with CasADi: pip install 'delaycomp[native]'")
    translation = translate(model)
    check_closed_form("model_controller", translation)
    branch = next(i for i, choice in enumerate(translation.choices)
                  if all(ctrl.p.get(k) == v for k, v in choice.items()))
    zoh = isinstance(ctrl, ZOHModelController)
    has_step = ("step", branch) in translation.functions
    predictor = PREDICTORS[slave.predictor]
    W = ctrl.history.W
    # what the C uses (an unused static function is a warning, and -Werror an error): the
    # prediction flows only over a window (W > 0); z flows at every step (continuous)
    needs_ode = (predictor == PREDICTORS["numerical"] and W > 0) or (not zoh and not has_step)
    uses_step = has_step and ((predictor == PREDICTORS["closed"] and W > 0) or not zoh)
    D = ctrl.pad_line.D if zoh else 0
    p = [float(ctrl.p[name]) for name in translation.numeric]  # T included, last
    funcs = (*(("f",) if needs_ode else ()), "k", *(("step",) if uses_step else ()))
    dims, state = _model_layout(prefix, model.n, model.m, W, D, zoh, needs_ode)
    notes = _model_notes(prefix, loop, slave, zoh, D, W, needs_ode)
    header = _header(prefix, loop, dims, state, notes)
    args = {"x": "x", "u": "u", "p": prefix + "_P", "t": "t", "h": "h"}
    template = (_templates() / "export" / "model.c.in").read_text(encoding="utf-8")
    source = _fill(template, prefix, {
        "MODEL": model.name, "LOOP": loop.name, "VERSION": __version__,
        "ZOH": str(int(zoh)), "PREDICT": str(predictor), "HAS_STEP": str(int(uses_step)),
        "NEEDS_ODE": str(int(needs_ode)), "TOL": _c(slave.tolerance),
        "TAU": _c(slave.tau), "NP": str(max(len(p), 1)),
        "P": _array(p), "U0": _array(slave.u0),
        "GRID_RTOL": repr(GRID_RTOL), "MAX_ODE_STEPS": str(MAX_ODE_STEPS),
        "Z0": _array(slave.z0),
        "ODE": _ode_source() if needs_ode else "",
        "FUNCTIONS": _model_functions(translation, branch, funcs),
        "CALL_F": _call(translation, "f", branch, args, "dx") if needs_ode else "-1",
        "CALL_K": _call(translation, "k", branch, args),
        "CALL_STEP": _call(translation, "step", branch, args) if uses_step else "-1",
        "COMMON": _common()})
    return header, source


def _model_layout(P: str, n: int, m: int, W: int, D: int, zoh: bool,
                  needs_ode: bool) -> tuple[dict[str, int], str]:
    """The dimensions (``P_NAME`` macros) and the state struct's fields of a model's
    controller."""
    state = [_COMMON_STATE,
             "    long hist_head;     /* ring position of the oldest stored control */",
             f"    double hist[{P}_HIST][{P}_NU];  /* the controls of the window, a ring */"]
    if zoh:
        state += ["    long pad_head;      /* ring position of the oldest padded control */",
                  f"    double pad[{P}_PAD][{P}_NU];  /* the output's padding delay line */",
                  f"    double held[{P}_NU];  /* the control held over the period */",
                  f"    double pending[{P}_NU];  /* u_i from the current sample */"]
    else:
        state += [f"    double z[{P}_NY];  /* the predictor state z(t_k) */",
                  f"    double zpending[{P}_NY];  /* z reset by the current sample */"]
    if needs_ode:
        state += [f"    double work[{P}_WORK];  /* the ODE integrator's work memory */"]
    dims = {"NY": n, "NU": m, "W": W, "HIST": max(W, 1)}
    if zoh:
        dims |= {"D": D, "PAD": max(D, 1)}
    if needs_ode:
        dims["WORK"] = _ODE_WORK_PER_STATE * n
    return dims, "\n".join(state)


def _model_notes(P: str, loop, slave, zoh: bool, D: int, W: int,
                 needs_ode: bool) -> list[str]:
    """The header's lines on a model's controller: family, predictor, timing, window."""
    ctrl, model = slave.ctrl, slave.model
    family = ("zero-order hold (Theorem 3.2)" if zoh
              else "continuous input (Theorem 2.1)")
    return [f"Model {model.name}: {family}, predictor {slave.predictor}; n = {model.n} "
            f"states, m = {model.m} inputs;",
            f"T = {loop.T!r}, N = {loop.N}, r = {float(slave.r)!r}, "
            f"tau = {float(slave.tau)!r}"
            + (f" (padded to {float(ctrl.tau_effective)!r}: the output is delayed by "
               f"{D} base steps)" if zoh and D else "") + ";",
            f"the window holds W = {W} base steps of controls"
            + (f"; each numerical flow tries at most {P}_MAX_ODE_STEPS + 1 DOP853 steps "
               "(a prediction: all its segments together)" if needs_ode else "") + "."]


def _ode_source() -> str:
    """DOP853 (fmus/native/ode.h and ode.c) as static functions of the exported file."""
    native = _templates()
    ode_h = (native / "ode.h").read_text(encoding="utf-8")
    ode_c = (native / "ode.c").read_text(encoding="utf-8").replace(
        '#include "ode.h"\n', "")
    return "#define ODE_API static\n" + ode_h + "\n" + ode_c


def closed_loop_io(loop, ticks: int, fmu_dir: str | Path | None = None):
    """The controller's measurements and outputs in a closed-loop run of ``loop``'s native
    FMUs, at each of ``ticks`` base steps from ``t0 = 0``: what to drive an exported
    controller with, to compare it with the FMU (``tests/test_exportc.py``) or to time it
    on a real trajectory (``bench/run.py`` section 11).

    The FMUs are stepped as our master steps them: at ``t_k`` the plant's outputs go to
    the measurement delay, its outputs to the controller, the controller's to the input
    delay and on to the plant (Gauss-Seidel along the chain), then each FMU steps to
    ``t_{k+1}``.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``ys`` (ticks x n: the controller's inputs) and ``us`` (ticks x m: its outputs).
    """
    from delaycomp.fmu.twins import native_fmus
    from delaycomp.orchestrator.fmu import FmuComponent

    fmus = native_fmus(loop, Path(fmu_dir) if fmu_dir is not None else None)
    order = ["plant", "meas_delay", "controller", "input_delay"]
    comps: dict = {}
    try:
        for name in order:
            inst = next(i for i in loop.instances if i.name == name)
            comps[name] = comp = FmuComponent(name, fmus[name])
            comp.setup(0.0, ticks * loop.h, dict(inst.parameters))
            comp.initialize()
        ys, us = [], []
        for k in range(ticks):
            for i, name in enumerate(order):
                src, dst = comps[name], comps[order[(i + 1) % 4]]
                values = src.get_outputs(src.output_names)
                if name == "meas_delay":
                    ys.append(values)
                elif name == "controller":
                    us.append(values)
                dst.set_inputs(dst.input_names, values)
            for comp in comps.values():
                comp.do_step(k * loop.h, loop.h)
    finally:
        for comp in comps.values():
            comp.terminate()
    return np.array(ys, dtype=float), np.array(us, dtype=float)


def export_c(loop, out_dir: str | Path, prefix: str) -> list[Path]:
    """Write the controller of ``loop`` as ``out_dir/prefix.h`` and ``out_dir/prefix.c``.

    Parameters
    ----------
    loop : Loop
        A loop (a loop file's, a scenario's) whose controller is delaycomp's: LTI, or a
        model file's (both families, every predictor, padding).
    out_dir : path
        The folder to write into (created); nothing is written elsewhere.
    prefix : str
        The C prefix of every exported name (a C identifier).

    Returns
    -------
    list of Path
        The two files written.

    Examples
    --------
    >>> import tempfile
    >>> from delaycomp.paper import scenarios
    >>> sc = scenarios.get("example-3.6")
    >>> loop = sc.make(sc.resolve([]))
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     [p.name for p in export_c(loop, tmp, "ctl")]
    ['ctl.h', 'ctl.c']
    """
    prefix = check_prefix(prefix)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ParameterError(f"--out {out_dir} is not allowed: it is a file (a folder is "
                             "needed)")
    _, kind, slave = _controller(loop)
    header, source = (_export_lti if kind == "controller" else _export_model)(
        prefix, loop, slave)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{prefix}.h", out_dir / f"{prefix}.c"]
    for path, text in zip(paths, (header, source)):
        write_text(path, text)  # whole, never through a link
    return paths
