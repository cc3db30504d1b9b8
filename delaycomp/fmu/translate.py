"""A model file's functions as C: traced with CasADi symbols, emitted as straight-line C.

The first piece of the native nonlinear FMUs: ``translate`` calls the
model's ``f``, ``k`` and ``step`` once per combination of its string parameters' choices
(``CHOICES``) with symbolic arguments (CasADi's ``SX``): the state, the input, the time or
the step, and every numeric parameter (``T``, the sampling period, among them), so one C
function serves every parameter value and one branch serves each choice. CasADi builds the
expression graph with common subexpressions shared; ``emit_c`` writes its instructions
as C99, one local per register, constants exact (their shortest round-trip decimal), no
heap, no library but ``math.h``.

What traces: arithmetic, numpy's functions (``np.sin``, ``np.where``, ``np.clip``,
``x @ y``, ...) and ``math``'s (``math.cos(x[2])``) on the state, tuples and arrays, Python
branches on string parameters (``p["law"] == "printed"``). What does not: Python control
flow on the state or on a numeric parameter (``if x[0] > 0``, ``max(x[0], 1)``), and
``float()`` or ``int()`` of them; such a function is refused with one line naming the
function, the operation and the line of the user's file (``TranslationError``). The
Python FMUs run every model.

CasADi is an optional dependency (``pip install 'delaycomp[native]'``); it is imported
here only.

Examples
--------
>>> from delaycomp.maths.model import load_model
>>> from delaycomp.paper.models import path
>>> tr = translate(load_model(path("example_3_8")))
>>> tr.numeric, [c["p"] for c in tr.choices]
(('T',), ['square', 'sin'])
>>> print(tr.functions["k", 1].signature)
int k_1(const double *x, const double *p, double *out)
"""

from __future__ import annotations

import contextlib
import itertools
import linecache
import math
import re
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from delaycomp.errors import DelaycompError
from delaycomp.maths.model import Model, ModelError

#: the functions of the model interface that are translated, and their C parameters:
#: ``x`` (n), ``u`` (m), ``t``, ``h`` and ``p`` (the numeric parameters, ``T`` last)
SIGNATURES = {
    "f": ("x", "u", "p"),
    "k_continuous": ("t", "x", "p"),
    "k_zoh": ("x", "p"),
    "step": ("x", "u", "h", "p"),
}


class TranslationError(ModelError):
    """A model function cannot be translated to C (one line: function, operation, line)."""


class _Untraceable(DelaycompError):
    """Raised inside a trace where Python needs a number from a symbol."""


@dataclass(frozen=True)
class CFunction:
    """One traced function for one choice of the string parameters, as C."""

    #: the C name, ``<function>_<choice index>``
    name: str
    #: the C parameters, in order (``x``, ``u``, ``t``, ``h``, ``p``)
    args: tuple[str, ...]
    #: the number of outputs (written to ``out``)
    n_out: int
    #: the C definition
    code: str

    @property
    def signature(self) -> str:
        """The C prototype: ``int <name>(<args>, double *out)``, ``t`` and ``h`` as
        ``double``, the vectors as ``const double *``."""
        params = ", ".join(f"double {a}" if a in ("t", "h") else f"const double *{a}"
                           for a in self.args)
        return f"int {self.name}({params}, double *out)"


@dataclass(frozen=True)
class Translation:
    """The C functions of a model (``translate``)."""

    model: Model
    #: one dict of string-parameter values per branch, in the order of the C names' index
    choices: tuple[dict, ...]
    #: the numeric parameters in the order of the C array ``p`` (``T`` last)
    numeric: tuple[str, ...]
    #: ``(function, choice index) -> CFunction`` for ``f``, ``k`` and ``step``
    functions: dict = field(default_factory=dict)
    #: functions the model gives that did not translate, with the reason (``step``)
    untranslated: dict = field(default_factory=dict)

    def source(self) -> str:
        """The C file: every function, preceded by ``math.h`` (C99, no heap)."""
        head = (f"/* {self.model.name}: f, k and step as C, traced by delaycomp.fmu.translate. "
                "p = {" + ", ".join(self.numeric) + "}. Branches: "
                + "; ".join(f"{i}: {c}" for i, c in enumerate(self.choices)) + ". */\n"
                "#include <math.h>\n")
        return head + "".join("\n" + fn.code for fn in self.functions.values())

    def c_files(self) -> dict[str, str]:
        """``model.h`` and ``model.c`` for a native FMU: the functions ``static``, and one
        entry point per function that dispatches on the branch, ``gen_f(branch, x, u, p,
        out)``, ``gen_k(...)`` and (``MODEL_HAS_STEP``) ``gen_step(...)``; each returns 0,
        or -1 for a branch out of range. ``MODEL_NP`` is the length of ``p``,
        ``MODEL_NBRANCH`` the number of branches."""
        names = sorted({name for name, _ in self.functions})
        h = ["/* Generated by delaycomp.fmu.translate from model "
             f"{self.model.name}: see model.c. */", "#ifndef DELAYCOMP_MODEL_H",
             "#define DELAYCOMP_MODEL_H", "",
             f"#define MODEL_NP {len(self.numeric)}",
             f"#define MODEL_NBRANCH {len(self.choices)}",
             f"#define MODEL_HAS_STEP {int('step' in names)}", ""]
        c = [self.source().replace("#include <math.h>\n", "#include <math.h>\n\n"
                                    "#include \"model.h\"\n"), ""]
        for name in names:
            fn = self.functions[name, 0]
            params = fn.signature.split("(", 1)[1].rsplit(")", 1)[0]
            proto = f"int gen_{name}(int branch, {params})"
            h.append(f"{proto};")
            call = ", ".join((*fn.args, "out"))
            c += [f"{proto} {{", "    switch (branch) {"]
            c += [f"    case {i}: return {name}_{i}({call});"
                  for i in range(len(self.choices))]
            c += ["    default: return -1;", "    }", "}", ""]
        h += ["", "#endif", ""]
        code = "\n".join(c)
        for name in names:  # the per-branch functions are internal to model.c
            code = re.sub(rf"^int ({name}_\d+\()", r"static int \1", code, flags=re.M)
        return {"model.h": "\n".join(h), "model.c": code}


# -- tracing ----------------------------------------------------------------------------------

_MATH_NAMES = ("sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "asinh",
               "acosh", "atanh", "exp", "expm1", "log", "log1p", "sqrt", "fabs", "floor",
               "ceil", "erf", "atan2", "hypot", "copysign", "fmod", "pow")


@contextlib.contextmanager
def _tracing(ca):
    """``math``'s functions accept symbols; ``float()``, ``int()`` and truth values of a
    symbol raise ``_Untraceable`` (CasADi returns NaN for ``float()``)."""
    saved_math = {name: getattr(math, name) for name in _MATH_NAMES}
    saved_sx = {name: ca.SX.__dict__.get(name) for name in ("__float__", "__int__",
                                                             "__bool__", "__index__")}

    def symbolic(name, plain):
        fn = getattr(ca, {"fabs": "fabs", "pow": "power"}.get(name, name))

        def call(*args):
            if any(isinstance(a, ca.SX) for a in args):
                return fn(*args)
            return plain(*args)
        return call

    def refuse(what):
        def raiser(self, *args):
            raise _Untraceable(what)
        return raiser

    try:
        for name, plain in saved_math.items():
            setattr(math, name, symbolic(name, plain))
        ca.SX.__float__ = refuse("float() of a value that depends on the state, the "
                                 "input or a numeric parameter")
        ca.SX.__int__ = refuse("int() of a value that depends on the state, the input or "
                               "a numeric parameter")
        ca.SX.__index__ = ca.SX.__int__
        ca.SX.__bool__ = refuse("a Python branch (if, and, or, min, max, ...) on a value "
                                "that depends on the state, the input or a numeric "
                                "parameter: use np.where or np.clip")
        yield
    finally:
        for name, plain in saved_math.items():
            setattr(math, name, plain)
        for name, value in saved_sx.items():
            if value is None:
                with contextlib.suppress(AttributeError):
                    delattr(ca.SX, name)
            else:
                setattr(ca.SX, name, value)


def _where(exc: BaseException, skip: tuple[str, ...]) -> str:
    """``file:line (`source`)`` of the innermost frame of the user's code."""
    frames = [fr for fr in traceback.extract_tb(exc.__traceback__)
              if not any(s in fr.filename for s in skip)]
    if not frames:
        return "an unknown line"
    fr = frames[-1]
    # a frame of a traceback has its line number (typeshed allows None)
    text = (fr.line or linecache.getline(fr.filename, cast(int, fr.lineno))).strip()
    return f"{Path(fr.filename).name}:{fr.lineno} (`{text}`)"


def _column(ca, values, want: int, what: str):
    """The traced result as an ``want`` x 1 SX column."""
    flat = np.ravel(np.asarray(values, dtype=object))
    if flat.size != want:
        raise _Untraceable(f"{what} returned {flat.size} values, must be {want}")
    cells = []
    for v in flat:
        if isinstance(v, ca.SX):
            cells.append(v)
        elif isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
            cells.append(ca.SX(float(v)))
        else:
            raise _Untraceable(f"{what} returned {type(v).__name__} {v!r}, not a number")
    return ca.vertcat(*cells)


def _casadi():
    try:
        import casadi as ca
    except ImportError:
        raise ModelError("translating a model to C needs CasADi: pip install "
                         "'delaycomp[native]' (or run the Python FMUs)") from None
    with contextlib.suppress(AttributeError):  # the symbolic numpy behaviour, no notice
        ca.GlobalOptions.setNumpyMode(-1)
    return ca


def translate(model: Model) -> Translation:
    """Trace ``f``, ``k`` and (where it traces) ``step`` of ``model`` into C functions.

    Raises
    ------
    TranslationError
        ``f`` or ``k`` does not trace (the function, the operation and the line), or a
        string parameter has no ``CHOICES`` (its values must be known to branch on them).
    """
    ca = _casadi()
    free = sorted(k for k, v in model.parameters.items()
                  if isinstance(v, str) and k not in model.choices)
    if free:
        raise TranslationError(f"model {model.name}: string parameter {free[0]!r} has no "
                               "CHOICES: the C functions need its values listed")
    numeric = (*sorted(k for k, v in model.parameters.items()
                       if not isinstance(v, str) and k != "T"), "T")
    keys = sorted(model.choices)
    choices = tuple(dict(zip(keys, combo))
                    for combo in itertools.product(*(model.choices[k] for k in keys)))
    n, m = model.n, model.m
    sym = {"x": ca.SX.sym("x", n), "u": ca.SX.sym("u", m), "t": ca.SX.sym("t"),
           "h": ca.SX.sym("h"), "p": ca.SX.sym("p", len(numeric))}
    cells = {name: np.array([sym[name][i] for i in range(sym[name].numel())], dtype=object)
             for name in ("x", "u", "p")}
    k_kind = "k_continuous" if model.control == "continuous" else "k_zoh"
    wanted = [("f", "f", model.f, n), ("k", k_kind, model.k, m)]
    if model.step is not None:
        wanted.append(("step", "step", model.step, n))
    skip = (str(Path(__file__).resolve()), f"{Path(np.__file__).parent}",
            f"{Path(ca.__file__).parent}", "<frozen ")
    functions, untranslated = {}, {}
    with _tracing(ca):
        for name, kind, fn, width in wanted:
            args = SIGNATURES[kind]
            traced = {}  # a function translates for every branch or not at all
            for index, choice in enumerate(choices):
                p = {**model.parameters, **choice}
                p.update({key: cells["p"][i] for i, key in enumerate(numeric)})
                call = [p if a == "p" else cells[a] if a in cells else sym[a] for a in args]
                try:
                    out = _column(ca, fn(*call), width, f"{name}({', '.join(args)})")
                except (_Untraceable, RuntimeError, TypeError, ValueError) as exc:
                    what = str(exc).splitlines()[0] if isinstance(exc, _Untraceable) \
                        else f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
                    label = f" with {choice}" if choice else ""
                    reason = (f"model {model.name}: {name}{label} cannot be translated to "
                              f"C: {what}, at {_where(exc, skip)}; the Python FMUs run it")
                    if name != "step":
                        raise TranslationError(reason) from None
                    untranslated[name] = reason
                    break
                cname = f"{name}_{index}"
                func = ca.Function(cname, [sym[a] for a in args], [out])
                traced[name, index] = CFunction(cname, args, width,
                                                emit_c(ca, func, cname, args))
            else:
                functions.update(traced)
    return Translation(model, choices, numeric, functions, untranslated)


# -- C ----------------------------------------------------------------------------------------

def _c_ops(ca) -> dict:
    """CasADi's SX operations as C expressions of their arguments ``a`` and ``b``."""
    ops = {
        "ADD": "{a} + {b}", "SUB": "{a} - {b}", "MUL": "{a} * {b}", "DIV": "{a} / {b}",
        "NEG": "-{a}", "TWICE": "2.0 * {a}", "SQ": "{a} * {a}", "INV": "1.0 / {a}",
        "ASSIGN": "{a}", "EXP": "exp({a})", "LOG": "log({a})", "SQRT": "sqrt({a})",
        "POW": "pow({a}, {b})", "CONSTPOW": "pow({a}, {b})", "SIN": "sin({a})",
        "COS": "cos({a})", "TAN": "tan({a})", "ASIN": "asin({a})", "ACOS": "acos({a})",
        "ATAN": "atan({a})", "SINH": "sinh({a})", "COSH": "cosh({a})", "TANH": "tanh({a})",
        "ASINH": "asinh({a})", "ACOSH": "acosh({a})", "ATANH": "atanh({a})",
        "ATAN2": "atan2({a}, {b})", "EXPM1": "expm1({a})", "LOG1P": "log1p({a})",
        "HYPOT": "hypot({a}, {b})", "FABS": "fabs({a})", "FLOOR": "floor({a})",
        "CEIL": "ceil({a})", "FMOD": "fmod({a}, {b})", "ERF": "erf({a})",
        "FMIN": "fmin({a}, {b})", "FMAX": "fmax({a}, {b})", "COPYSIGN": "copysign({a}, {b})",
        "SIGN": "({a} > 0.0 ? 1.0 : ({a} < 0.0 ? -1.0 : {a}))",
        "LT": "({a} < {b} ? 1.0 : 0.0)", "LE": "({a} <= {b} ? 1.0 : 0.0)",
        "EQ": "({a} == {b} ? 1.0 : 0.0)", "NE": "({a} != {b} ? 1.0 : 0.0)",
        "NOT": "({a} == 0.0 ? 1.0 : 0.0)", "AND": "(({a} != 0.0 && {b} != 0.0) ? 1.0 : 0.0)",
        "OR": "(({a} != 0.0 || {b} != 0.0) ? 1.0 : 0.0)",
        "IF_ELSE_ZERO": "({a} != 0.0 ? {b} : 0.0)",
    }
    return {getattr(ca, f"OP_{k}"): v for k, v in ops.items() if hasattr(ca, f"OP_{k}")}


def _literal(value: float) -> str:
    """A double constant, exact: Python's shortest round-trip decimal."""
    if math.isnan(value):
        return "NAN"
    if math.isinf(value):
        return "INFINITY" if value > 0 else "-INFINITY"
    text = repr(float(value))
    return text if re.search(r"[.eE]", text) else text + ".0"


def emit_c(ca, func, name: str, args: tuple[str, ...]) -> str:
    """The C definition of the CasADi SX function ``func`` (inputs ``args``, one output
    column written to ``out``): one local per register of its algorithm, returning 0.

    Raises
    ------
    TranslationError
        An operation with no C form here (named by its CasADi code).
    """
    ops = _c_ops(ca)
    names = {v: k for k, v in vars(ca).items() if k.startswith("OP_") and isinstance(v, int)}
    body = []
    for i in range(func.n_instructions()):
        op = func.instruction_id(i)
        ins, outs = func.instruction_input(i), func.instruction_output(i)
        if op == ca.OP_CONST:
            body.append(f"w{outs[0]} = {_literal(func.instruction_constant(i))};")
        elif op == ca.OP_INPUT:
            arg = args[ins[0]]
            body.append(f"w{outs[0]} = {arg if arg in ('t', 'h') else f'{arg}[{ins[1]}]'};")
        elif op == ca.OP_OUTPUT:
            body.append(f"out[{outs[1]}] = w{ins[0]};")
        elif op in ops:
            a = f"w{ins[0]}"
            b = f"w{ins[1]}" if len(ins) > 1 else ""
            body.append(f"w{outs[0]} = {ops[op].format(a=a, b=b)};")
        else:
            raise TranslationError(f"{name}: the operation {names.get(op, op)} has no C form "
                                   "in delaycomp.fmu.translate")
    params = ", ".join(f"double {a}" if a in ("t", "h") else f"const double *{a}"
                       for a in args)
    used = sorted({int(w) for w in re.findall(r"\bw(\d+)\b", " ".join(body))})
    lines = [f"int {name}({params}, double *out) {{"]
    if used:
        lines.append("    double " + ", ".join(f"w{w}" for w in used) + ";")
    for a in args:
        if not re.search(rf"\b{a}\b", " ".join(body)):
            lines.append(f"    (void){a};")
    lines += [f"    {line}" for line in body] + ["    return 0;", "}", ""]
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover - print a model's C: python -m ... FILE.py
    from delaycomp.maths.model import load_model

    print(translate(load_model(sys.argv[1])).source())
