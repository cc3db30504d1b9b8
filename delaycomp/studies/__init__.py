"""Studies over many loops: parameter sweeps (``.sweep``, with the grid axes in
``.axes`` and the worker pool in ``.pool``), the batch engine (``.batch``,
``.sweep_batch``) and the critical delay (``.critical``).
"""
