"""delaycomp: predictor-based delay compensation for sampled-data control, as FMUs.

The package stands in layers, each a folder, imports only downward: the maths, free of FMI
(``delaycomp.maths``: exact discretization, predictor maps, the controllers, the grid),
the typed loop (``delaycomp.system``), the paper as data (``delaycomp.paper``), the
FMUs' build side (``delaycomp.fmu``), the master (``delaycomp.orchestrator``) and
the FMUs (``delaycomp.fmus``), what it writes and reads (``delaycomp.formats``),
studies (``delaycomp.studies``) and verification (``delaycomp.verify``), and the face
(``delaycomp.api``, ``delaycomp.cli``). ``delaycomp.layout`` finds a checkout's top-level
folders (``orchestrator/``, ``fmus/``, ``reference/``) under these names.

The Python API is importable from here: ``delaycomp.run``, ``delaycomp.load``,
``delaycomp.lti``, ``delaycomp.sweep``, ... are ``delaycomp.api``'s, imported on first
use (PEP 562), so that ``import delaycomp`` stays light.

This module must stay light: it is imported inside every FMU.
"""

import importlib

from delaycomp import layout
from delaycomp.version import __version__ as __version__

# in a Python FMU's bundled copy, the rest of the package too (delaycomp.layout.whole)
__path__ = layout.whole(__name__, __path__)

layout.install()

#: the public API (``delaycomp.api``), each name imported from there on first access
_API = ("BadFileError", "DelaycompError", "Loop", "ModelError", "ParameterError", "Result",
        "SignError", "SimulationFailed", "build", "choose_fmus", "critical_delay",
        "critical_delay_report", "critical_delay_table", "export_c", "iter_sweep", "load",
        "lti", "model", "plot", "robustness", "run", "sweep", "to_ssp")

__all__ = list(_API)


def __getattr__(name: str):
    """An API name, from ``delaycomp.api`` (imported on first access)."""
    if name in _API:
        return getattr(importlib.import_module("delaycomp.api"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the API's."""
    return sorted({*globals(), *_API})
