"""The two tiers of the suite: the fast one (the README's test command, ``pytest``) and the
slow one (``pytest -m slow``; ``.ci/run`` runs both, so CI runs every test there is).

A matrix keeps the cases that check each behaviour once in the fast tier and puts the rest,
the same checks on more cases, into the slow tier: ``tiered(values, fast)``.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from typing import Any

import pytest

slow = pytest.mark.slow
#: the type of ``pytest.param(...)`` (pytest does not export it)
_PARAM = type(pytest.param(None))


def tiered(values: Iterable[Any], fast: int | Collection[Any] = 1) -> list[Any]:
    """``values`` for ``pytest.mark.parametrize``, those past the first ``fast`` (an int) or
    not among ``fast`` (a collection) marked ``slow``; a tuple is the values of several
    argnames (as ``parametrize`` reads it); a ``pytest.param`` keeps its id and marks.

    Examples
    --------
    >>> [p.marks for p in tiered(["a", "b", "c"], 2)]
    [(), (), (MarkDecorator(mark=Mark(name='slow', args=(), kwargs={})),)]
    >>> [bool(p.marks) for p in tiered(["a", "b", "c"], {"c"})]
    [True, True, False]
    >>> [(p.values, bool(p.marks)) for p in tiered([("lti", 0), ("lti", 1)], {("lti", 1)})]
    [(('lti', 0), True), (('lti', 1), False)]
    """
    out = []
    for i, value in enumerate(values):
        if isinstance(value, _PARAM):
            param = value
        else:  # a tuple holds the values of several argnames, as parametrize reads it
            param = pytest.param(*value) if isinstance(value, tuple) else pytest.param(value)
        key = param.values[0] if len(param.values) == 1 else param.values
        keep = i < fast if isinstance(fast, int) else key in fast
        marks = tuple(param.marks) + (() if keep else (slow,))
        out.append(pytest.param(*param.values, id=param.id, marks=marks))
    return out
