"""Studies over many loops: parameter sweeps (:mod:`.sweep`, with the grid axes in
:mod:`.axes` and the worker pool in :mod:`.pool`), the batch engine (:mod:`.batch`,
:mod:`.sweep_batch`) and the critical delay (:mod:`.critical`).
"""
