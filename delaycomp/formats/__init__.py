"""What delaycomp writes and reads: SSP files (:mod:`.ssp`: write, read, archive), the
outputs of runs (:mod:`.outputs`), your loop's FMUs with their wiring sheet
(:mod:`.loopbuild`) and the controller as plain C (:mod:`.exportc`).
"""
