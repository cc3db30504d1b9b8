"""Your controller in a host of your own, on fmpy, with no delaycomp code at run time.

First build the loop's FMUs (delaycomp is needed for this step only)::

    delaycomp build docs/examples/cart.toml --out fmus

then wire them as ``fmus/cart_wiring.txt`` says and step them::

    python docs/examples/controller_alone.py fmus [STOP_TIME]

Every FMU keeps its start values (the loop's): this script sets no parameter. It prints
the plant's state at the stop time, as ``delaycomp run docs/examples/cart.toml`` has it.
Swap ``cart_plant.fmu`` for a plant FMU of your own tool with the same inputs and
outputs, or the two delay FMUs for your network, and the controller stays as it is.
"""

import shutil
import sys
import tempfile
from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

# from the wiring sheet: sampling period T, base step h = T/N, and the signal chain
T, N = 1.0, 20
CHAIN = ["plant", "meas_delay", "controller", "input_delay"]  # each one's outputs feed
# the next one's inputs, in modelDescription order (plant.x1 -> meas_delay.u1, ...)


def open_fmu(path: Path, workdir: Path):
    md = read_model_description(str(path))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path), str(workdir)),
                      modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=path.stem)
    ins = [v.valueReference for v in md.modelVariables if v.causality == "input"]
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    names = [v.name for v in md.modelVariables if v.causality == "output"]
    return slave, ins, outs, names


def main(folder: Path, stop: float = 10.0) -> None:
    work = Path(tempfile.mkdtemp())
    fmus = {role: open_fmu(folder / f"cart_{role}.fmu", work / role) for role in CHAIN}
    h = T / N
    for slave, *_ in fmus.values():
        slave.instantiate()
        slave.setupExperiment(startTime=0.0, stopTime=stop)
        slave.enterInitializationMode()  # no parameter set: the start values are the loop's
        slave.exitInitializationMode()
    ticks = round(stop / h)
    for k in range(ticks + 1):
        t = k * h  # t_k = t0 + k h, never t += h
        # the plant's outputs at t_k, then along the chain: each delay and the controller
        # see their inputs at t_k before their outputs are read (Gauss-Seidel)
        for i, role in enumerate(CHAIN):
            src, _, outs, _ = fmus[role]
            dst, ins, _, _ = fmus[CHAIN[(i + 1) % len(CHAIN)]]
            dst.setReal(ins, src.getReal(outs))
        if k == ticks:
            break
        for slave, *_ in fmus.values():
            slave.doStep(currentCommunicationPoint=t, communicationStepSize=h)
    plant, _, outs, names = fmus["plant"]
    print(", ".join(f"{n} = {v:.12g}" for n, v in zip(names, plant.getReal(outs))))
    for slave, *_ in fmus.values():
        slave.terminate()
        slave.freeInstance()
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "fmus"),
         float(sys.argv[2]) if len(sys.argv) > 2 else 10.0)
