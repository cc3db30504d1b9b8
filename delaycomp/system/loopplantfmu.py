"""A loop file around another tool's plant FMU: ``[plant] fmu = "Plant.fmu"`` with the
predictor's model from ``[controller]`` (``A``, ``B`` and ``K``; a model file; or
``predictor = "plant-fmu"``, the FMU's own Model Exchange derivatives), checked key by key
and built by ``delaycomp.system.plantfmu``.

The reader (``delaycomp.system.loopfile``) hands such a file's tables here.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from delaycomp.errors import ParameterError
from delaycomp.system.loop import Loop, check_zoh_delay
from delaycomp.system.loopkeys import DEFAULTS, allowed
from delaycomp.system.loopvalues import (
    array_value,
    check_keys,
    check_sign,
    check_value,
    flag_value,
    model_value,
    real_value,
)


def fmu_plant(plant: dict, ctrl: dict, base: Path, where: str, T, N, r, tau, mode,
              common: dict) -> Loop:
    """``[plant] fmu = "Plant.fmu"``: a user's FMU as the plant (``.plantfmu``)."""
    from delaycomp.system.plantfmu import fmu_plant_loop

    check_keys(f"{where} [plant]", plant, allowed("plant", "fmu-lti"))
    for key in ("states", "inputs", "x0"):
        if key not in plant:
            raise ParameterError(f"{where}: plant.{key} is required with plant.fmu ("
                                 + {"states": "the FMU outputs that form the measured state x",
                                    "inputs": "the FMU inputs that receive u",
                                    "x0": "the history of x on [-r, 0]"}[key] + ")")
    if not isinstance(plant["fmu"], str):
        raise ParameterError(f"plant.fmu = {plant['fmu']!r} is not allowed: must be a path")
    fmu = Path(plant["fmu"])
    fmu = fmu if fmu.is_absolute() else (base / fmu).resolve()
    x0 = array_value("plant.x0", plant["x0"], 1)
    if ctrl.get("predictor") == "plant-fmu":
        return _plant_fmu_predictor(plant, ctrl, fmu, where, T, N, r, tau, x0, common)
    if ("A" in ctrl) == ("model" in ctrl):
        raise ParameterError(f"{where}: with plant.fmu the predictor's model comes from "
                             "[controller]: A and B (LTI, with K) or model = \"file.py\"")
    if "A" in ctrl:
        check_keys(f"{where} [controller]", ctrl, allowed("controller", "fmu-lti"))
        if "B" not in ctrl or "K" not in ctrl:
            raise ParameterError(f"{where}: an LTI predictor needs controller.A, "
                                 "controller.B and controller.K")
        A = array_value("controller.A", ctrl["A"], 2)
        B = array_value("controller.B", ctrl["B"], 2)
        K = array_value("controller.K", ctrl["K"], 2)
        u0 = array_value("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else None
        pad = check_value("controller.pad", ctrl.get("pad", DEFAULTS["controller.pad"]))
        loop = fmu_plant_loop(fmu, plant["states"], plant["inputs"],
                              plant.get("parameters"), T, r, tau, N, x0, u0, A=A, B=B, K=K,
                              mode=mode, start=plant.get("start"), pad=pad, **common)
        if not flag_value("controller.allow_unstable",
                          ctrl.get("allow_unstable", DEFAULTS["controller.allow_unstable"])):
            check_sign(A, B, K, T)
        return loop
    model_path = Path(str(ctrl["model"]))
    if not model_path.is_absolute():
        model_path = (base / model_path).resolve()
    from delaycomp.maths.model import load_model

    model = load_model(model_path)
    keys = allowed("controller", "fmu-model")
    params = {}
    for key, value in ctrl.items():
        if key in ("model", "u0", "mode"):
            # mode (compensated or not) is the loop's, applied below as predictor = none;
            # the model controller FMU's own "mode" parameter is its model's CONTROL
            continue
        if key not in keys and key not in model.parameters:
            raise ParameterError(f"{where} [controller]: unknown key {key!r}: allowed are "
                                 f"{', '.join([*keys, *model.parameters])}")
        params[key] = (model_value(model, key, value) if key in model.parameters
                       else real_value("controller.tolerance", value, positive=True)
                       if key == "tolerance" else check_value(f"controller.{key}", value))
    params.setdefault("pad", DEFAULTS["controller.pad"])
    if mode == "uncompensated":
        params["predictor"] = "none"
    u0 = array_value("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else None
    return fmu_plant_loop(fmu, plant["states"], plant["inputs"], plant.get("parameters"),
                          T, r, tau, N, x0, u0, model=model_path,
                          controller_parameters=params, start=plant.get("start"), **common)


def _plant_fmu_predictor(plant: dict, ctrl: dict, fmu: Path, where: str, T, N, r, tau,
                         x0, common: dict) -> Loop:
    """``predictor = "plant-fmu"``: the plant FMU's Model Exchange derivatives as the
    predictor's model (``.fmumodel``), its state found from the measured outputs, with
    ``u = K y``."""
    from delaycomp.maths.predictors import DEFAULT_TOL
    from delaycomp.system.fmumodel import start_from_outputs, write_model
    from delaycomp.system.plantfmu import (
        check_mapping,
        check_output_map,
        fmu_plant_loop,
        histories,
        read_interface,
    )

    check_keys(f"{where} [controller]", ctrl, allowed("controller", "fmu-plant-fmu"))
    if "K" not in ctrl:
        raise ParameterError(f"{where}: controller.predictor = \"plant-fmu\" needs "
                             "controller.K (u = K x)")
    iface = read_interface(fmu)
    if iface.model_exchange is None:
        raise ParameterError(f"controller.predictor = \"plant-fmu\" is not allowed: "
                             f"{fmu.name} has no Model Exchange interface (give A and B, or "
                             "model)")
    states, inputs, values = check_mapping(iface, plant["states"], plant["inputs"],
                                           plant.get("parameters"), start=plant.get("start"))
    check_output_map(iface, states)
    K = array_value("controller.K", ctrl["K"], 2)
    tol = DEFAULT_TOL
    if "tolerance" in ctrl:
        tol = real_value("controller.tolerance", ctrl["tolerance"], positive=True)
        if not tol < 1:
            raise ParameterError(f"controller.tolerance = {tol!r} is not allowed: must be in "
                                 "(0, 1)")
    model = write_model(fmu, states, inputs, iface.states, K, values, tolerance=tol)
    start = plant.get("start")
    x0, _ = histories(x0, None, states, inputs)  # x0 checked before it is inverted
    if start is None and all(iface.variables[x].initial == "exact" for x in iface.states):
        # x0 applied through the start values of the FMU's states, found from the outputs'
        # map (the model module makes the FMI calls)
        start = start_from_outputs(model, fmu.name, x0)
        values = {**values, **start}
        model = write_model(fmu, states, inputs, iface.states, K, values, tolerance=tol)
    mode = ctrl.get("mode", DEFAULTS["controller.mode"])
    params: dict = {"predictor": "none" if mode == "uncompensated" else "closed"}
    u0 = array_value("controller.u0", ctrl["u0"], 1) if "u0" in ctrl else None
    check_zoh_delay(tau, T)  # u = K x held over each period; no padding here
    return fmu_plant_loop(fmu, states, inputs, plant.get("parameters"), T, r, tau, N, x0, u0,
                          model=model, controller_parameters=params, start=start, **common)


def fmu_tolerance(plant: dict, make: Callable[[], Loop]) -> Loop:
    """The loop of a plant FMU (``make()``) with ``[plant] tolerance``, checked first, for
    its ``fmi2SetupExperiment`` (``with_tolerance``)."""
    from delaycomp.system.plantfmu import check_tolerance, with_tolerance

    tol = plant.get("tolerance")
    tol = None if tol is None else check_tolerance(tol)
    return with_tolerance(make(), tol)
