"""delaycomp: predictor-based delay compensation for sampled-data control, as FMUs.

The subpackages are kept free of FMI so that the maths can be tested and reused on its
own: :mod:`delaycomp.lti` (exact discretization, the lifted closed loop),
:mod:`delaycomp.predictor` (the predictor map of Corollary 3.4),
:mod:`delaycomp.controller` (the zero-order-hold controller of Theorem 3.2) and
:mod:`delaycomp.delayline` (a transport delay on a fixed grid).

This module must stay light: it is imported inside every FMU.
"""

__version__ = "0.1.0"
