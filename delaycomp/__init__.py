"""delaycomp: predictor-based delay compensation for sampled-data control, as FMUs.

The package stands in layers, each a folder, imports only downward: the maths, free of FMI
(:mod:`delaycomp.maths`: exact discretization, predictor maps, the controllers, the grid),
the typed loop (:mod:`delaycomp.system`), the paper as data (:mod:`delaycomp.paper`), the
FMUs' build side (:mod:`delaycomp.fmu`), the master (:mod:`delaycomp.orchestrator`) and
the FMUs (:mod:`delaycomp.fmus`), what it writes and reads (:mod:`delaycomp.formats`),
studies (:mod:`delaycomp.studies`) and verification (:mod:`delaycomp.verify`), and the face
(:mod:`delaycomp.api`, :mod:`delaycomp.cli`). :mod:`delaycomp.layout` keeps the modules'
earlier names importable.

This module must stay light: it is imported inside every FMU.
"""

from delaycomp import layout

__version__ = "0.1.0"

# in a Python FMU's bundled copy, the rest of the package too (delaycomp.layout.whole)
__path__ = layout.whole(__name__, __path__)

layout.install()
