"""Names shared by the FMU slaves, the system model and the scenarios: the controller's
modes and the names of vector signals. Standard library only, so that what only names
things (``delaycomp list``, ``--help``) imports no maths."""

import re

#: the controller's modes: the predictor's ``u = K Phi(y, past inputs)`` or ``u = K y``
MODES: tuple[str, ...] = ("compensated", "uncompensated")

#: which FMUs a command or API call uses: the native C FMUs where the loop has them here,
#: only native ones, or the Python (pythonfmu) ones
FMU_KINDS: tuple[str, ...] = ("auto", "native", "python")

#: ``delaycomp build LOOP.toml --only GROUP``: the roles of the loop each group builds
LOOP_GROUPS: dict[str, tuple[str, ...]] = {"plant": ("plant",), "controller": ("controller",),
                                           "delays": ("meas_delay", "input_delay")}


#: the build configuration a Python FMU keeps in ``resources/`` (its dimensions, names,
#: version; a native FMU's says ``"native": true``)
CONFIG_NAME = "delaycomp_fmu.json"

#: suffix of the Integer twin ``<name>_index`` of a String parameter with a fixed set of
#: choices (``delaycomp.fmu.slave``, point 9)
INDEX_SUFFIX = "_index"


def indexed(base: str, count: int) -> list[str]:
    """``[base]`` for one channel, ``[base1, ..., baseN]`` otherwise."""
    return [base] if count == 1 else [f"{base}{i + 1}" for i in range(count)]


#: an element of a vector or matrix as the FMI 2.0 FMUs name their scalars (``x0[2]``,
#: ``A[2,1]``: indices from 1), which FMI 3.0 FMUs hold in one array variable
_ELEMENT = re.compile(r"^(\w+)\[(\d+(?:,\d+)*)\]$")


def array_element(name: str) -> tuple[str, tuple[int, ...]] | None:
    """The array and the indices (from 1) of an element's name, else None.

    >>> array_element("A[2,1]"), array_element("x0[3]"), array_element("T")
    (('A', (2, 1)), ('x0', (3,)), None)
    """
    m = _ELEMENT.match(name)
    return (m.group(1), tuple(int(i) for i in m.group(2).split(","))) if m else None


def flat_index(index: tuple[int, ...], shape: tuple[int, ...]) -> int | None:
    """The row-major position of the element ``index`` (from 1) in an array of ``shape``,
    or None where it lies outside.

    >>> flat_index((2, 1), (3, 3)), flat_index((3,), (2,))
    (3, None)
    """
    if len(index) != len(shape) or not all(1 <= i <= e for i, e in zip(index, shape)):
        return None
    flat = 0
    for i, extent in zip(index, shape):
        flat = flat * extent + (i - 1)
    return flat
