"""What delaycomp writes and reads: SSP files (``.ssp``: write, read, archive), the
outputs of runs (``.outputs``), your loop's FMUs with their wiring sheet
(``.loopbuild``) and the controller as plain C (``.exportc``).
"""
