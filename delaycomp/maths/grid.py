"""The base grid: the one module that decides what lies on it.

A loop runs on integer ticks ``t_k = t0 + k h`` of the base step ``h = T / N``. Delays,
windows, stop times and sampling periods enter as real numbers and must be whole numbers
of a step (``h``, a communication step, or ``T``); every such question in the package is
asked here, with one tolerance (``GRID_RTOL``) and one bound (``MAX_STEPS``).
This module imports nothing of the package: the maths, the FMUs and the system model all
stand on it.

Examples
--------
>>> on_grid(0.3, 0.01), on_grid(0.305, 0.01)
(True, False)
>>> steps_of(0.3, 0.1, "r")          # 0.3 / 0.1 is 2.9999999999999996
3
>>> split(2.5, 1.0)
(2, 0.5)
>>> same_step(0.3 - 0.2, 0.1)        # 0.09999999999999998: the step 0.1 of the grid
True
"""

from __future__ import annotations

import math

#: Relative slack when deciding whether a value is a whole number of a step: round-off of
#: decimal inputs (``0.3 / 0.1``) is about 1e-16 relative; 1e-9 leaves room for sums of a
#: few such values and still refuses any value a user could mean as off the grid.
GRID_RTOL = 1e-9
#: Longest buffer (delay line, input history, predictor window) in steps: a bad parameter
#: (a huge delay, a tiny step) must be refused, not allocate until the host is killed.
#: 10^6 steps of a scalar signal take about 80 MB once filled.
MAX_STEPS = 1_000_000
#: the unit round-off of a double (2^-52): ``same_step``'s allowance for the host's times
_EPS = 2.0 ** -52
#: The most a host's clock may drift off an FMU's grid, relative to the step
#: (``drift``): a host that keeps time as ``t += h`` (OpenModelica, OMSimulator) is
#: 1.7e-5 h off after 10^6 steps of ``h = 0.01`` (measured); a step ``h (1 + 1e-3)`` or a
#: jump is refused.
DRIFT_RTOL = 1e-4


def nearest_multiple(value: float, step: float) -> int | None:
    """``k`` with ``value = k step`` up to ``GRID_RTOL``, else ``None``."""
    ratio = value / step
    if not math.isfinite(ratio):
        return None
    k = round(ratio)
    if abs(ratio - k) <= GRID_RTOL * max(1.0, abs(ratio)):
        return int(k)
    return None


def on_grid(value: float, step: float) -> bool:
    """Is ``value`` an integer multiple of ``step`` (up to round-off)?"""
    return nearest_multiple(value, step) is not None


def on_grid_array(values, step):
    """``on_grid`` elementwise over arrays (``values`` and ``step`` broadcast), with the
    same floating-point arithmetic: the same answer for every element.

    >>> on_grid_array([0.3, 0.305, float("nan")], 0.01).tolist()
    [True, False, False]
    """
    import numpy as np

    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.asarray(values, dtype=float) / np.asarray(step, dtype=float)
        return np.isfinite(ratio) & (np.abs(ratio - np.rint(ratio))
                                     <= GRID_RTOL * np.maximum(1.0, np.abs(ratio)))


def same_step(step: float, h: float, t: float = 0.0) -> bool:
    """Is ``step`` the step ``h`` of an FMU's own grid, up to round-off of the host's times?

    The one rule by which an FMU that keeps something per step size (the plant's
    discretization ``Ad(h), Bd(h)``, the delay's line of ``delay / h`` steps) decides that
    a communication step ``(t, step)`` is the one it already knows: ``|step - h| <=
    GRID_RTOL h + 8 eps max(|t|, |t + step|)``, the grid's tolerance and the round-off of
    the host's times near ``t``. The native FMUs use the same arithmetic (``same_step`` of
    ``fmus/native/native.c``).

    A host that keeps time exactly (``t_k = t0 + k h``, as the FMI guides ask) passes
    steps ``t_{k+1} - t_k = h (1 + d)``: each time is rounded (``k h``, then ``t0 + k h``,
    each off by ``eps / 2`` of itself, ``eps = 2^-52``) and so is their difference, so
    ``|d| <= (2 k + 3 + |t0| / h) eps``, and ``|d| <= (k + 1) eps`` from ``t0 = 0``; in
    absolute terms ``|d| h`` is a few ulps of ``t``, which the second term covers however
    long the run or far from 0 its start (from ``t = 1e5`` with ``h = 0.005``, ``d`` is
    ``3e-9``, beyond ``GRID_RTOL`` alone). Reusing the plant's ``Ad(h)`` for a step
    ``h (1 + d)`` errs by ``~ |d| h |x'|`` against that step, and not at all against the
    grid ``t0 + k h`` the host means.

    Parameters
    ----------
    step : float
        The communication step the host passed (finite, > 0).
    h : float
        The step the FMU keys its data on (> 0).
    t : float
        Where the step starts (the round-off of the host's times grows with ``|t|``).

    Returns
    -------
    bool
        True when ``step`` is ``h`` up to ``GRID_RTOL`` relative to ``h`` and the
        round-off of the times near ``t``.

    Examples
    --------
    >>> h = 0.01
    >>> [same_step((k + 1) * h - k * h, h) for k in (0, 7, 123456)]
    [True, True, True]
    >>> same_step(h * (1 + 1e-12), h), same_step(h * (1 + 1e-6), h), same_step(h / 2, h)
    (True, False, False)
    >>> h = 0.005
    >>> step = (1e5 + 2 * h) - (1e5 + h)   # 3e-9 h off: the round-off of times near 1e5
    >>> same_step(step, h), same_step(step, h, 1e5 + h)
    (False, True)
    """
    return abs(step - h) <= GRID_RTOL * h + 8 * _EPS * max(abs(t), abs(t + step))


def drift(t: float, h: float, t0: float = 0.0) -> float:
    """How far a host's time ``t`` may lie from the point ``t0 + k h`` of an FMU's grid
    that it means: the round-off of a clock kept as ``t += h``.

    Each addition rounds once, by at most ``eps / 2`` of the sum (``eps = 2^-52``), so after
    ``k = |t - t0| / h`` additions the host is off by at most ``k eps max(|t0|, |t|) / 2``;
    twice that, plus 8 ulps for a host that computes ``t0 + k h`` instead, is allowed, and
    never more than ``DRIFT_RTOL`` ``h`` (so a step ``h (1 + 1e-3)`` or a jump of a
    step stays refused however long the run). The native FMUs use the same arithmetic
    (``drift`` of ``fmus/native/native.c``).

    >>> t = 0.0
    >>> for _ in range(10_000):
    ...     t += 0.01
    >>> t - 100.0, drift(t, 0.01) > abs(t - 100.0)  # 1.4e-9 h ahead: beyond GRID_RTOL h
    (1.425348727934761e-11, True)
    >>> drift(1e9, 0.01) == DRIFT_RTOL * 0.01
    True
    """
    scale = max(abs(t), abs(t0))
    return min((abs(t - t0) / h + 8) * _EPS * scale, DRIFT_RTOL * h)


def on_tick(t: float, t_tick: float, T: float, t0: float = 0.0) -> bool:
    """Is a host's time ``t`` the tick ``t_tick`` of a periodic clock of interval ``T``
    started at ``t0``: within ``GRID_RTOL T`` and the ``drift`` of a host clock kept in
    steps of ``T / 1000`` or more (its communication points lie ``T / MAX_STEPS`` apart at
    least: far more)? The clocked native FMUs use the same arithmetic (``at_next_tick`` of
    ``fmus/native/fmi3.c``), and our master decides so when a clocked FMU ticks.

    >>> on_tick(0.2 + 1e-15, 0.2, 0.2), on_tick(0.21, 0.2, 0.2)
    (True, False)
    """
    return abs(t - t_tick) <= GRID_RTOL * T + drift(t, T * 1e-3, t0)


def grid_step(t: float, step: float, h: float, t0: float) -> bool:
    """Is ``[t, t + step]`` one step of the grid ``t0 + k h``, each end within
    ``GRID_RTOL h +`` ``drift`` of consecutive grid points?

    The rule by which an FMU on its own grid takes a host's step whose ends drifted
    (``t += h``: a last step ``stop - t`` to the stop time is ``h`` less the drift); the FMU
    then advances to its own ``t0 + (k + 1) h``, never taking on the host's drift.

    >>> t = 0.0
    >>> for _ in range(9_999):
    ...     t += 0.01
    >>> step = 100.0 - t                              # a last step to stop time 100
    >>> same_step(step, 0.01, t), grid_step(t, step, 0.01, 0.0)
    (False, True)
    >>> grid_step(t, 0.01 * 1.001, 0.01, 0.0), grid_step(t, 0.02, 0.01, 0.0)
    (False, False)
    """
    if not (math.isfinite(t) and math.isfinite(step) and h > 0 and math.isfinite(t0)):
        return False
    k = round((t - t0) / h)
    end = t + step
    return (abs(t - (t0 + k * h)) <= GRID_RTOL * h + drift(t, h, t0)
            and abs(end - (t0 + (k + 1) * h)) <= GRID_RTOL * h + drift(end, h, t0))


def check_steps(name: str, value: float, steps: float, unit: str) -> None:
    """Refuse a window of more than ``MAX_STEPS`` steps of ``unit``."""
    if not steps <= MAX_STEPS:
        raise ValueError(f"{name} = {value!r} is not allowed: must be at most {MAX_STEPS} "
                         f"{unit} (it needs {steps:.6g})")


def steps_of(value: float, step: float, name: str, what: str | None = None) -> int:
    """``k`` with ``value = k step``, ``0 <= k <= MAX_STEPS``; else ``ValueError`` naming
    ``name`` and the grid (``what``, default "the base step h = <step>")."""
    what = what or f"the base step h = {step!r}"
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"step size must be a finite number > 0, got {step!r}")
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} = {value!r} is not allowed: must be a finite number >= 0")
    check_steps(name, value, value / step, f"steps of {what}")
    k = nearest_multiple(value, step)
    if k is None:
        raise ValueError(f"{name} = {value!r} is not allowed: must be a multiple of {what}")
    return k


def steps_up(value: float, step: float) -> int:
    """The first grid point at or after ``value``: the least ``k`` with ``k step >= value``,
    a whole multiple up to ``GRID_RTOL`` taken as it is (a packet delayed by ``0.36`` on
    ``h = 0.01`` is seen 36 steps later, not 37). ``value`` finite and ``>= 0``.

    >>> steps_up(0.36, 0.01), steps_up(0.361, 0.01), steps_up(0.0, 0.01)
    (36, 37, 0)
    """
    k = nearest_multiple(value, step)
    return k if k is not None else math.ceil(value / step)


def split(value: float, period: float) -> tuple[int, float]:
    """``(q, rest)`` with ``q = [value / period]`` and ``rest = value - q period`` in
    ``[0, period)``.

    When ``value / period`` is an integer up to round-off (``0.3 / 0.1``) that integer is
    taken and ``rest = 0``: a floor of the raw quotient would put almost a whole period into
    ``rest``.
    """
    if not period > 0:
        raise ValueError(f"T must be > 0, got {period}")
    if value < 0:
        raise ValueError(f"r must be >= 0, got {value}")
    k = nearest_multiple(value, period)
    if k is not None:
        return k, 0.0
    q = math.floor(value / period)
    return q, max(value - q * period, 0.0)


def padded_delay(tau: float, T: float) -> float:
    """``ceil(tau / T) T`` (Remark 3.3(b)), with ``tau`` that is a multiple of ``T`` up to
    round-off kept (the model and LTI controllers' ``pad``).

    >>> padded_delay(0.7, 0.5), padded_delay(0.6, 0.2)
    (1.0, 0.6)
    """
    q, rest = split(tau, T)
    return tau if rest == 0.0 else (q + 1) * T


def _show(x: float) -> str:
    """A value the message computed (a multiple, a quotient): 12 significant digits, so
    that round-off (``3 * 0.3 = 0.8999999999999999``) does not show."""
    return f"{x:.12g}"


#: how ``pad`` is spelled where it is offered (Remark 3.3(b)), for the messages
PAD_SPELLING = "pad = true ([controller] pad in a loop file, --set pad=1 for a scenario)"


def base_alternatives(value: float, period: float, N: int) -> str:
    """The fix for a delay ``value`` off the base grid ``h = period / N``: the nearest
    multiples of ``h``, and the smallest ``N' >= N`` (if one up to ``MAX_STEPS``
    exists) whose grid holds ``value``; never "raise N" where no larger ``N`` helps
    (``r = 0.5``, ``T = 0.3``: only ``N`` a multiple of 3 does).

    >>> base_alternatives(0.305, 1.0, 100)
    'the nearest allowed are 0.3 or 0.31, or N = 200 puts it on the grid'
    >>> base_alternatives(0.5, 0.3, 100)
    'the nearest allowed are 0.498 or 0.501, or N = 102 puts it on the grid'
    """
    from fractions import Fraction

    h = period / N
    q = math.floor(value / h)
    text = f"the nearest allowed are {_show(q * h)} or {_show((q + 1) * h)}"
    ratio = Fraction(value / period).limit_denominator(MAX_STEPS)
    d = ratio.denominator
    better = d * -(-N // d)
    if better <= MAX_STEPS and on_grid(value, period / better):
        text += f", or N = {better} puts it on the grid"
    return text


def zoh_alternatives(value: float, period: float) -> str:
    """The allowed values nearest to a ``tau = value`` that is no multiple of ``T =
    period``: the multiples of ``T`` below and above it, and the periods ``T = tau/l``
    below and above ``period`` (the fix where ``T`` is what varies: a sweep over ``T``).

    >>> zoh_alternatives(2.5, 1.0)
    'the nearest allowed are tau = 2 or 3 (l*T), or T = 0.833333333333 or 1.25 (tau/l)'
    >>> zoh_alternatives(0.5, 1.0)
    'the nearest allowed are tau = 0 or 1 (l*T), or T = 0.5 (tau/l)'
    """
    q = math.floor(value / period)
    text = (f"the nearest allowed are tau = {_show(q * period)} or "
            f"{_show((q + 1) * period)} (l*T)")
    below, above = value / (q + 1), (value / q if q >= 1 else None)
    periods_near = [_show(below)] + ([_show(above)] if above is not None else [])
    return text + f", or T = {' or '.join(periods_near)} (tau/l)"


def periods(value: float, period: float, name: str = "tau", padding: bool = False,
            hints: bool = False) -> int:
    """``l`` with ``value = l period``, ``l >= 0``: under zero-order hold the input delay
    is a whole number of sampling periods (Theorem 3.2, ``tau = l T``), up to round-off as
    ``split`` decides it.

    The rule and its message, written once: the typed loop
    (``delaycomp.system.loop.check_zoh_delay``), the scenarios, the batch engine and
    the controllers (the FMUs) call it. The message is one line; with ``hints`` (the
    typed loop's and the batch engine's checks, which the commands report) it tells the
    fix: the nearest allowed ``tau`` (multiples of ``T``) and ``T`` (``tau / l``, for a
    sweep over ``T``), and where the caller can pad, that ``pad = true`` accepts ``tau``
    as it is. The FMUs log the short form, word for word what their C twins log.

    Parameters
    ----------
    padding : bool
        The caller could pad the delay up (Remark 3.3(b)): the message says how, and to
        what.
    hints : bool
        Name the nearest allowed values and how to pad (else the FMUs' short form).

    Raises
    ------
    ValueError
        ``value`` is not such a multiple (or not a finite number >= 0), naming it and ``T``.

    Examples
    --------
    >>> import re
    >>> periods(0.6, 0.2)
    3
    >>> for padding in (False, True):
    ...     try:
    ...         periods(2.5, 1.0, padding=padding, hints=True)
    ...     except ValueError as exc:
    ...         for part in re.split(r"(?<=:) (?=the)|; | (?=accepts)", str(exc)):
    ...             print(part)
    tau = 2.5 is not allowed: zero-order hold needs a multiple l*T (l >= 0) of T = 1.0:
    the nearest allowed are tau = 2 or 3 (l*T), or T = 0.833333333333 or 1.25 (tau/l)
    tau = 2.5 is not allowed: zero-order hold needs a multiple l*T (l >= 0) of T = 1.0:
    the nearest allowed are tau = 2 or 3 (l*T), or T = 0.833333333333 or 1.25 (tau/l)
    or pad = true ([controller] pad in a loop file, --set pad=1 for a scenario)
    accepts it, delaying the output to the next multiple, 3 (Remark 3.3(b))
    """
    usable = math.isfinite(value) and value >= 0 and math.isfinite(period) and period > 0
    if usable:
        q, rest = split(value, period)
        if rest == 0.0:
            return q
    text = (f"{name} = {value!r} is not allowed: zero-order hold needs a multiple l*T "
            f"(l >= 0) of T = {period!r}")
    if not hints:
        if padding and usable:
            text += f"; pad = true pads it up to {(q + 1) * period!r} (Remark 3.3(b))"
        raise ValueError(text)
    if usable:
        text += f": {zoh_alternatives(value, period)}"
    if padding and usable:
        text += (f"; or {PAD_SPELLING} accepts it, delaying the output to the next "
                 f"multiple, {_show((q + 1) * period)} (Remark 3.3(b))")
    raise ValueError(text)


def ticks(duration: float, T: float, N: int, name: str = "--stop-time") -> int:
    """Base steps ``k >= 1`` with ``duration = k h``, ``h = T / N``, for a duration > 0; a
    duration that rounds to no step at all (shorter than ``h``, or ``h`` itself beyond
    what a float divides: ``1e-320`` against ``h = 0.01``, ``1`` against ``h = 1e10``) is
    refused, never run as zero steps.

    >>> ticks(2.0, 1.0, 100)
    200
    >>> ticks(1e-320, 1.0, 100)
    Traceback (most recent call last):
    ...
    ValueError: --stop-time 1e-320 is not allowed: it is less than one base step h = T/N = 0.01
    """
    h = T / N
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"{name} {duration!r} is not allowed: must be a finite number > 0")
    k = nearest_multiple(duration, h)
    if k == 0:
        raise ValueError(f"{name} {duration!r} is not allowed: it is less than one base "
                         f"step h = T/N = {h!r}")
    if k is None:
        raise ValueError(f"{name} {duration!r} is not allowed: must be a multiple of the "
                         f"base step h = T/N = {h!r}")
    return k


def tick_time(k: int, t0: float, T: float, h: float, N: int) -> float:
    """The time of tick ``k`` of the base grid ``h = T / N`` from ``t0``: ``t0 + (k // N) T
    + (k % N) h``, exact at every sampling instant (the master's ``time_of``; the native
    stepping core computes it the same way).

    >>> tick_time(250, 0.0, 1.0, 0.01, 100)
    2.5
    """
    i, j = divmod(k, N)
    return t0 + i * T + j * h
