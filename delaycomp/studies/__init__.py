"""Studies over many loops: parameter sweeps (``.sweep``, with the grid axes in
``.axes``, the worker pool in ``.pool``, the size estimates in ``.sweep_size`` and the
output in ``.sweep_output``), the batch engine (``.batch``, a package of one engine a
module, and ``.sweep_batch``) and the critical delay (``.critical``).
"""
