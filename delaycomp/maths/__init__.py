"""The maths, free of FMI (numpy and scipy only): the grid (``.grid``), exact
discretization and the lifted loop (``.lti``), predictor maps (``.predictors``), the
zero-order-hold controller of Theorem 3.2 (``.zoh``), the controllers of model files
(``.nlcontrol``), the model-file interface (``.model``), input histories
(``.history``) and the delay line (``.delayline``).

This is what the Python FMUs bundle: the package imports nothing, and its modules import
only each other and ``delaycomp``'s light base (errors, names).
"""
