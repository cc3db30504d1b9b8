"""The maths, free of FMI (numpy and scipy only): the grid (:mod:`.grid`), exact
discretization and the lifted loop (:mod:`.lti`), predictor maps (:mod:`.predictors`), the
zero-order-hold controller of Theorem 3.2 (:mod:`.zoh`), the controllers of model files
(:mod:`.nlcontrol`), the model-file interface (:mod:`.model`), input histories
(:mod:`.history`) and the delay line (:mod:`.delayline`).

This is what the Python FMUs bundle: the package imports nothing, and its modules import
only each other and :mod:`delaycomp`'s light base (errors, names).
"""
