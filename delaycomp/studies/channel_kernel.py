"""The channel batch's draws, compiled: ``fmus/native/fates.c`` through ctypes.

``delaycomp.maths.channel_batch.shown`` draws every packet's fate of every run with numpy,
some thirty passes over arrays of packets x runs: with a packet every base step that is
three quarters of a Monte Carlo run's time. The same computation in C walks each run's
packets once (``fates.c``, the draws of ``draws.c`` that the channel FMU uses): the same
integers, bit for bit (``tests/test_channel_kernel.py``), several times faster.

It is compiled on first use with the C compiler the native FMUs use
(``delaycomp.fmu.native.compiler``: ``$CC``, else Zig's from the ``native`` extra, else
``cc``, ``gcc`` or ``clang``; no fused multiply-add, so every double is numpy's) into a
temporary folder, loaded, and the folder removed. Where no compiler is found or the build
fails, ``shown`` returns ``None`` and the batch draws with numpy (the same numbers,
slower); ``status`` says which and why.
"""

from __future__ import annotations

import ctypes
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from delaycomp.maths import grid
from delaycomp.maths.channel import DISTRIBUTIONS, LOSS_MODELS, POLICIES, Channel

_LIB: ctypes.CDLL | None = None
_STATUS: str | None = None
_I64 = ctypes.POINTER(ctypes.c_int64)
_U64 = ctypes.POINTER(ctypes.c_uint64)
_F64 = ctypes.POINTER(ctypes.c_double)


def _build() -> ctypes.CDLL:
    """Compile and load ``fates.c`` (raises where it cannot)."""
    from delaycomp.fmu.native import SOURCE_DIR, compiler

    suffix = ".dll" if sys.platform == "win32" else ".so"
    with tempfile.TemporaryDirectory(prefix="delaycomp-fates-",
                                     ignore_cleanup_errors=True) as tmp:
        lib = Path(tmp) / f"fates{suffix}"
        argv = [*compiler(), "-std=c11", "-O2", "-fPIC", "-shared", "-ffp-contract=off",
                "-I", str(SOURCE_DIR), str(SOURCE_DIR / "fates.c"),
                str(SOURCE_DIR / "draws.c"), "-o", str(lib), "-lm"]
        done = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
        if done.returncode != 0:
            first = (done.stderr.strip().splitlines() or ["(no message)"])[0]
            raise OSError(f"the compiler failed: {first}")
        return ctypes.CDLL(str(lib))  # loaded: the file may go (POSIX)


def _load() -> ctypes.CDLL | None:
    global _LIB, _STATUS
    if _STATUS is None:
        try:
            lib = _build()
        except Exception as exc:  # noqa: BLE001 - any failure: numpy's draws, said in status
            _STATUS = f"numpy (the compiled draws are not available: {exc})"
            return None
        lib.fates_shown.restype = ctypes.c_int
        lib.fates_shown.argtypes = [ctypes.c_int64, _U64, _I64, _F64, _I64, _F64, _I64]
        _LIB, _STATUS = lib, "compiled C (fmus/native/fates.c)"
    return _LIB


def status() -> str:
    """Which draws the channel batch uses on the CPU, ``compiled C`` or ``numpy (... why)``
    (compiling on the first call)."""
    _load()
    assert _STATUS is not None
    return _STATUS


def _ptr(a: np.ndarray, kind):
    return a.ctypes.data_as(kind)


def shown(channel: Channel, seeds, h: float, steps: int, every: int = 1) -> np.ndarray | None:
    """``delaycomp.maths.channel_batch.shown`` compiled: the send step of the packet each
    run's channel shows at steps ``0 .. steps - 1`` (every ``every``-th), shape ``(rows,
    R)``, ``-1`` before any; ``None`` where the compiled draws are not available.

    Examples
    --------
    A constant delay of two steps shows packet ``k - 2``:

    >>> got = shown(Channel(delay=0.02), [0], 0.01, 5)
    >>> got is None or got[:, 0].tolist() == [-1, -1, 0, 1, 2]
    True
    """
    from delaycomp.maths import channel_batch as cb

    lib = _load()
    if lib is None:
        return None
    P, Q, J, rows = cb.sizes(channel, h, steps, every)
    keys = np.ascontiguousarray(cb.stream_keys(np.asarray(seeds).reshape(-1)))
    offs = np.ascontiguousarray(cb.offsets(channel, keys), dtype=np.int64)
    R = keys.size
    trace = np.ascontiguousarray(channel.trace if channel.distribution == "trace" else [0.0],
                                 dtype=float)
    par = np.array([channel.delay, channel.jitter, channel.shape, channel.loss, channel.p_gb,
                    channel.p_bg, channel.loss_good, channel.loss_bad, h, grid.GRID_RTOL],
                   dtype=float)
    ipar = np.array([DISTRIBUTIONS.index(channel.distribution),
                     LOSS_MODELS.index(channel.loss_model), POLICIES.index(channel.policy),
                     Q, P, J, every, rows,
                     len(channel.trace) if channel.distribution == "trace" else 0],
                    dtype=np.int64)
    best = np.full((rows, R), -1, dtype=np.int64)
    rc = lib.fates_shown(R, _ptr(keys, _U64), _ptr(offs, _I64), _ptr(par, _F64),
                         _ptr(ipar, _I64), _ptr(trace, _F64), _ptr(best, _I64))
    if rc != 0:  # the checks above keep every parameter in range
        raise RuntimeError(f"fates_shown refused its parameters (rc = {rc})")
    return best if P == 1 else np.where(best >= 0, best * P, -1)
