"""The system model: the typed description of a closed loop (``.loop``), the loop file
that describes one in TOML (``.loopfile``) and the rewrites that work on roles
(``.jacobi``). It stands on the maths and ``delaycomp.maths.grid``, and imports nothing
above it (no FMI, no master).
"""

from delaycomp.system.loop import (
    ROLES,
    BuiltinFmu,
    Connection,
    FmuFile,
    Instance,
    Loop,
    LtiBatch,
    LtiDesign,
    LtiPoint,
    ModelFmu,
    Origin,
    Port,
    Role,
    Source,
    Timing,
    check_zoh_delay,
    design_loop,
    lti_design,
    lti_designs,
    lti_loop,
    model_loop,
)

__all__ = ["ROLES", "BuiltinFmu", "Connection", "FmuFile", "Instance", "Loop", "LtiBatch",
           "LtiDesign", "LtiPoint", "ModelFmu", "Origin", "Port", "Role", "Source", "Timing",
           "check_zoh_delay", "design_loop", "lti_design", "lti_designs", "lti_loop", "model_loop"]
