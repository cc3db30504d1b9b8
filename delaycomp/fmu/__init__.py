"""The FMUs' build side: the pythonfmu base slave (``.slave``, bundled into every
Python FMU), the registry and the build of the Python FMUs (``.build``), the build cache
(``.cache``), model files to C (``.translate``) and the native C build
(``.native``). The FMUs themselves live in ``delaycomp.fmus`` (``fmus/``).

This package imports only ``delaycomp.layout`` (``whole``):
the Python FMUs bundle it with the base slave.
"""

from delaycomp.layout import whole

__path__ = whole(__name__, __path__)
