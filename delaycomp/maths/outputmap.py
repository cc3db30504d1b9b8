"""The map from a plant's continuous states to its measured outputs, ``y = h(x)``, inverted.

A plant exported by a Modelica tool keeps its continuous states hidden and exposes sensor
outputs that are a function of them. ``predictor = "plant-fmu"`` measures ``y``, finds the
state ``x`` with ``h(x) = y`` (``invert``), predicts ``x`` with the plant's own
derivatives, and gives the feedback ``h`` of the prediction. This module is the maths of the
inversion only: ``h`` and its Jacobian are callables (through the FMU's Model Exchange
interface in the generated model module, ``delaycomp.system.fmumodel``).

The map must be locally injective: as many outputs as states or more, and a Jacobian
``dh/dx`` of full column rank (``check_rank``). Then Newton's method (Gauss-Newton,
with halving of the step while the residual does not decrease) from a nearby state
converges quadratically; for a linear ``h = C x + c`` it ends in one step.

Examples
--------
>>> import numpy as np
>>> C = np.array([[-1.0, 0.0], [-0.5, -1.0]])
>>> x = invert(lambda x: C @ x, lambda x: C, np.array([0.3, -0.2]), np.zeros(2))
>>> np.allclose(C @ x, [0.3, -0.2], rtol=0, atol=1e-15)
True
>>> check_rank(np.array([[1.0, 2.0]]), ["y"], ["a", "b"])  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
delaycomp.maths.outputmap.NotInvertible: the map from the outputs (y) to the states (a, b) ...
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from delaycomp.errors import DelaycompError

#: the Jacobian's condition number above which the map counts as not invertible: beyond
#: it, a round-off error of the outputs (eps |y|) moves the state found by more than
#: 1e-4 |x| relative
CONDITION_LIMIT = 1e12
#: the residual |h(x) - y| accepted, relative to 1 + |y| (inf-norms): round-off of the
#: outputs and of the Jacobian (the central differences' ~1e-10 relative error) with margin
RESIDUAL_RTOL = 1e-9


class NotInvertible(DelaycompError, ValueError):
    """The outputs do not determine the states (one-line message saying what to give)."""


def _names(names: Sequence[str]) -> str:
    return ", ".join(names)


def check_rank(J: np.ndarray, outputs: Sequence[str], states: Sequence[str],
               where: str = "") -> None:
    """Refuse a Jacobian ``dh/dx`` (outputs x states) that is not of full column rank (or is
    worse conditioned than ``CONDITION_LIMIT``), naming both sides; ``where``: the
    state at which it was taken, for the message."""
    J = np.atleast_2d(np.asarray(J, dtype=float))
    n_out, n_x = J.shape
    at = f" at x = {where}" if where else ""
    if n_out < n_x:
        raise NotInvertible(f"the map from the outputs ({_names(outputs)}) to the states "
                            f"({_names(states)}) is not invertible: {n_out} outputs for "
                            f"{n_x} states; name at least {n_x} outputs that determine the "
                            "states, or give A and B (or model) for the predictor")
    if not np.all(np.isfinite(J)):
        raise NotInvertible(f"the map from the outputs ({_names(outputs)}) to the states "
                            f"({_names(states)}) has a Jacobian that is not finite{at}")
    s = np.linalg.svd(J, compute_uv=False)
    if s[0] == 0 or s[-1] <= s[0] / CONDITION_LIMIT:
        rank = int(np.sum(s > s[0] / CONDITION_LIMIT)) if s[0] > 0 else 0
        raise NotInvertible(f"the map from the outputs ({_names(outputs)}) to the states "
                            f"({_names(states)}) is not invertible{at}: its Jacobian has "
                            f"rank {rank} of {n_x}; name outputs that determine every "
                            "state, or give A and B (or model) for the predictor")


def invert(h: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], np.ndarray],
           y, x_guess, max_iter: int = 50) -> np.ndarray:
    """The state ``x`` with ``h(x) = y`` (least squares where there are more outputs than
    states), by Newton's method from ``x_guess``; ``NotInvertible`` (one line) where
    the Jacobian loses rank or no state reaches ``y`` within ``RESIDUAL_RTOL``."""
    y = np.asarray(y, dtype=float)
    x = np.array(x_guess, dtype=float)
    r = np.asarray(h(x), dtype=float) - y
    scale = 1.0 + float(np.max(np.abs(y), initial=0.0))
    J = None
    for _ in range(max_iter):
        if not np.all(np.isfinite(r)):
            break
        if float(np.max(np.abs(r), initial=0.0)) <= 1e-3 * RESIDUAL_RTOL * scale:
            return x
        J = np.atleast_2d(np.asarray(jac(x), dtype=float))
        if not np.all(np.isfinite(J)):
            break
        dx = np.linalg.lstsq(J, -r, rcond=None)[0]
        norm = float(np.linalg.norm(r))
        step = 1.0
        for _ in range(30):  # halve the step until the residual decreases
            x_new = x + step * dx
            r_new = np.asarray(h(x_new), dtype=float) - y
            if np.all(np.isfinite(r_new)) and float(np.linalg.norm(r_new)) < norm:
                break
            step *= 0.5
        else:
            break  # no decrease along the Newton direction: converged to round-off
        small = float(np.max(np.abs(x_new - x), initial=0.0)) <= 1e-15 * (
            1.0 + float(np.max(np.abs(x_new), initial=0.0)))
        x, r = x_new, r_new
        if small:
            break
    if np.all(np.isfinite(r)) and float(np.max(np.abs(r), initial=0.0)) <= (
            RESIDUAL_RTOL * scale):
        return x
    raise NotInvertible(f"no state reaches the outputs y = {y.tolist()} (closest: "
                        f"h(x) - y = {r.tolist()} at x = {x.tolist()})")
