"""Names shared by the FMU slaves, the system model and the scenarios: the controller's
modes and the names of vector signals. Standard library only, so that what only names
things (``delaycomp list``, ``--help``) imports no maths."""

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
#: choices (``delaycomp.fmu.slave``, item 7)
INDEX_SUFFIX = "_index"


def indexed(base: str, count: int) -> list[str]:
    """``[base]`` for one channel, ``[base1, ..., baseN]`` otherwise."""
    return [base] if count == 1 else [f"{base}{i + 1}" for i in range(count)]
