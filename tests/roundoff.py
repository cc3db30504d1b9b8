"""Comparing computed numbers to round-off, the same on every machine.

The last bits of a computed float depend on more than the code: which kernel numpy's
bundled OpenBLAS picks for the processor (``OPENBLAS_CORETYPE``: SkylakeX, Haswell,
Sandybridge, Nehalem, ...) changes the order of the sums in every matrix product and whether
they use fused multiply-adds; another libm rounds ``exp`` differently; another scipy takes
other steps. So a test that compares floats produced in another process, by another
implementation, or against a committed file compares them to a tolerance, never byte for
byte. The tolerance is stated where it is used, in units of the machine epsilon ``EPS``
times a scale that belongs to the numbers:

- a signal (a column of a trace) is scaled by its peak: round-off made at the largest
  values a signal takes is carried into its later, smaller values (a dead-beat residual
  near zero is the round-off of the values it came from);
- a structure's numbers (a gain matrix, a parameter vector) are scaled by the largest
  magnitude in that array; a lone number by its own magnitude.

Byte equality stays where bytes are the contract: reproducible archives, generated text,
an FMU state restored into the same code in the same process.

Examples
--------
>>> assert_columns_close([[1.0, 2.0 + 2 * EPS]], [[1.0, 2.0]], ulps=4)
>>> assert_same_values({"K": [[-1.0, -2.0 + 4 * EPS]], "mode": "c"},
...                    {"K": [[-1.0, -2.0]], "mode": "c"}, ulps=4)
>>> assert_text_close('K = [[-1.0, -1.9999999999999991]]', 'K = [[-1.0, -2.0]]', ulps=8)
"""

from __future__ import annotations

import csv
import dataclasses
import math
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

#: the machine epsilon of float64, 2^-52
EPS = float(np.finfo(float).eps)

#: Two runs of the same arithmetic (the same FMUs or slaves, the same parameters, the same
#: order of calls) in two processes, or through two front ends (``run FILE.ssp`` and
#: ``run NAME``, a CSV and the API): equal on one machine, and on any machine at most the
#: last bits of each signal apart. 4 EPS of a column's peak is that; a real difference in
#: the loop (a sample one base step late, a parameter lost) is 1e-3 of the peak or more.
SAME_ARITHMETIC_ULPS = 4

#: The native C FMUs against the Python FMUs or their slaves in-process: the same maths,
#: its matrix exponentials and sums rounded by other code (C against scipy and numpy), so
#: a signal differs from its twin's by round-off that the loop carries along:
#: ``delaycomp.verify.check.NATIVE_RTOL``, 1e-12 of a signal's peak (measured at most
#: 4e-14 on every reference case). In EPS: about 4500.
NATIVE_ULPS = 1e-12 / EPS

#: A closed-form trace computed again (the exact-flow reference scripts, tests/
#: test_references.py): a few EPS per sample, carried along a loop that contracts or grows
#: with the signal itself; measured at most 1.8 EPS of a column's peak with the SkylakeX,
#: Haswell, Sandybridge and Nehalem kernels. 64 EPS of each column's peak.
EXACT_ULPS = 64

#: Committed numbers (the ``ssp/`` folder, the shipped loop files) against the code that
#: makes them, in EPS of the largest magnitude among them: typed values round-trip exactly
#: (17 significant digits); a computed one (a gain) may move in its last bits with another
#: BLAS kernel or libm. 16 EPS is a few last bits of the largest entry. (The dead-beat gain
#: of Corollary 3.7 is computed in exact rationals and rounded once, so it is in fact the
#: same on every machine.)
COMMITTED_ULPS = 16


def _excess(got: np.ndarray, want: np.ndarray, ulps: float, axis) -> tuple[np.ndarray, ...]:
    """Per-column error, peak and bound (``ulps * EPS * peak``) of ``got`` against ``want``;
    NaN must match NaN and infinities must be equal."""
    nan = np.isnan(want)
    assert np.array_equal(nan, np.isnan(got)), "NaN in one and not the other"
    inf = np.isinf(want)
    assert np.array_equal(got[inf], want[inf]), "infinities differ"
    finite = ~(nan | inf)
    w = np.where(finite, want, 0.0)
    g = np.where(finite, got, 0.0)
    err = np.max(np.abs(g - w), axis=axis, initial=0.0)
    peak = np.max(np.abs(w), axis=axis, initial=0.0)
    return err, peak, ulps * EPS * peak


def assert_columns_close(got, want, ulps: float, what: str = "", atol: float = 0.0) -> None:
    """``|got - want| <= ulps * EPS * (the column's peak |want|) + atol`` in every column.

    ``got`` and ``want`` have the same shape: rows of samples, one column per signal (a 1-D
    array is one signal). ``atol`` is for numbers that carry more than round-off (an ODE
    solver's tolerance); without it a column that is zero throughout must be zero.
    """
    g = np.asarray(got, dtype=float)
    w = np.asarray(want, dtype=float)
    assert g.shape == w.shape, f"{what}: shape {g.shape} against {w.shape}"
    if w.ndim == 1:
        g, w = g[:, None], w[:, None]
    err, peak, bound = _excess(g, w, ulps, axis=0)
    bad = np.flatnonzero(err > bound + atol)
    assert not bad.size, (
        f"{what}: column(s) {bad.tolist()} differ by {err[bad].tolist()} with peaks "
        f"{peak[bad].tolist()}: more than {ulps} EPS times the peak" +
        (f" + {atol:g}" if atol else ""))


def read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """A CSV with a header row and numbers below: the header and the numbers."""
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    data = np.array(rows[1:], dtype=float)
    return rows[0], data.reshape(len(rows) - 1, len(rows[0]))


def assert_csv_close(got: Path, want: Path, ulps: float, atol: float = 0.0,
                     hint: str = "") -> None:
    """Two CSV traces: the same header and number of rows, the numbers (time included) to
    ``assert_columns_close``; ``hint`` ends the message (how to regenerate a file)."""
    hg, g = read_table(got)
    hw, w = read_table(want)
    what = f"{Path(want).name}{' (' + hint + ')' if hint else ''}"
    assert hg == hw, f"{what}: header {hg} against {hw}"
    assert_columns_close(g, w, ulps, what=what, atol=atol)


def _numeric_array(value) -> np.ndarray | None:
    """``value`` as a float array if it is a number array or a (nested) list of numbers
    (not bools, which are compared exactly), else None."""
    if isinstance(value, np.ndarray):
        return value.astype(float) if value.dtype.kind in "fiu" else None
    if isinstance(value, (list, tuple)) and value:
        flat = list(value)
        while flat and all(isinstance(v, (list, tuple)) for v in flat):
            flat = [x for v in flat for x in v]
        if flat and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                        for v in flat) and any(isinstance(v, float) for v in flat):
            try:
                return np.array(value, dtype=float)
            except ValueError:  # ragged
                return None
    return None


def assert_same_values(a, b, ulps: float, where: str = "value") -> None:
    """``a == b`` with every float compared to round-off instead of bit for bit.

    Structure is compared exactly: the types, dataclass fields (those that take part in
    ``==``), mapping keys (in any order, as ``==`` does), sequence lengths, strings, ints
    and bools. A float or an array of floats (a matrix given as nested lists too) is
    compared to ``ulps * EPS`` times the largest magnitude in it (of either side).
    Anything else must be ``==``.
    """
    assert type(a) is type(b), f"{where}: {type(a).__name__} against {type(b).__name__}"
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        for f in dataclasses.fields(a):
            if f.compare:
                assert_same_values(getattr(a, f.name), getattr(b, f.name), ulps,
                                   f"{where}.{f.name}")
        return
    if isinstance(a, Mapping):
        assert set(a) == set(b), f"{where}: keys {sorted(a)} against {sorted(b)}"
        for k in a:
            assert_same_values(a[k], b[k], ulps, f"{where}[{k!r}]")
        return
    arr_a, arr_b = _numeric_array(a), _numeric_array(b)
    if arr_a is not None or arr_b is not None:
        assert arr_a is not None and arr_b is not None, f"{where}: {a!r} against {b!r}"
        assert arr_a.shape == arr_b.shape, f"{where}: shape {arr_a.shape} against {arr_b.shape}"
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype, f"{where}: dtype {a.dtype} against {b.dtype}"
        else:  # lists keep their element types (int stays int)
            assert _types(a) == _types(b), f"{where}: element types differ"
        scale = max(np.max(np.abs(arr_a), initial=0.0), np.max(np.abs(arr_b), initial=0.0))
        err = np.max(np.abs(arr_a - arr_b), initial=0.0)
        assert err <= ulps * EPS * scale, (
            f"{where}: differs by {err:.3g} with largest magnitude {scale:.3g}: more than "
            f"{ulps} EPS times it")
        return
    if isinstance(a, (list, tuple)):
        assert len(a) == len(b), f"{where}: length {len(a)} against {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_values(x, y, ulps, f"{where}[{i}]")
        return
    if isinstance(a, float):
        if math.isnan(a) or math.isnan(b):
            assert math.isnan(a) and math.isnan(b), f"{where}: {a!r} against {b!r}"
            return
        scale = max(abs(a), abs(b))
        assert a == b or abs(a - b) <= ulps * EPS * scale, (
            f"{where}: {a!r} against {b!r}: more than {ulps} EPS apart")
        return
    assert a == b, f"{where}: {a!r} against {b!r}"


def _types(value):
    if isinstance(value, (list, tuple)):
        return (type(value), tuple(_types(v) for v in value))
    return type(value)


#: a number in a text file (a decimal, an integer or an exponent form)
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def assert_text_close(got: str, want: str, ulps: float, what: str = "") -> None:
    """Two texts that hold computed numbers (an SSV parameter file, a loop file): the same
    text once every number is masked, and the numbers to ``ulps * EPS`` times the largest
    magnitude among the file's numbers (a computed gain is accurate relative to its norm,
    not entry by entry; typed numbers round-trip exactly and are equal anyway)."""
    skel_g, skel_w = NUMBER.sub("#", got).splitlines(), NUMBER.sub("#", want).splitlines()
    for i, (a, b) in enumerate(zip(skel_g, skel_w), 1):
        assert a == b, f"{what}: line {i} differs beyond its numbers: {a!r} against {b!r}"
    assert len(skel_g) == len(skel_w), f"{what}: {len(skel_g)} lines against {len(skel_w)}"
    g = np.array([float(x) for x in NUMBER.findall(got)])
    w = np.array([float(x) for x in NUMBER.findall(want)])
    scale = max(np.max(np.abs(g), initial=0.0), np.max(np.abs(w), initial=0.0))
    err = np.abs(g - w)
    bad = np.flatnonzero(err > ulps * EPS * scale)
    assert not bad.size, (f"{what}: numbers {g[bad][:5].tolist()} against "
                          f"{w[bad][:5].tolist()}: more than {ulps} EPS of {scale:g} apart")
