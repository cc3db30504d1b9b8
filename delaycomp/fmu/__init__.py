"""The FMUs' build side: the pythonfmu base slave (:mod:`.slave`, bundled into every
Python FMU), the registry and the build of the Python FMUs (:mod:`.build`), the build cache
(:mod:`.cache`), model files to C (:mod:`.translate`) and the native C build
(:mod:`.native`). The FMUs themselves live in :mod:`delaycomp.fmus` (``fmus/``).

This package imports only :mod:`delaycomp.layout` (:func:`~delaycomp.layout.whole`):
the Python FMUs bundle it with the base slave.
"""

from delaycomp.layout import whole

__path__ = whole(__name__, __path__)
