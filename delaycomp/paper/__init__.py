"""The paper as data: its cases as loop files (``loops/*.toml``), the model modules of
its nonlinear examples (``.models``) and the scenarios built from them
(``.scenarios``).

This package imports only ``delaycomp.layout`` (``whole``):
the FMUs bundle it with the models.
"""

from delaycomp.layout import whole

__path__ = whole(__name__, __path__)
