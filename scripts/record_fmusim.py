"""Record fmusim's runs of delaycomp's FMI 3.0 FMUs into ``reference/fmusim/``.

``fmusim`` (modelica/Reference-FMUs v0.0.39, the FMI standard's reference importer) is in
no package registry, so a machine without it (CI's, a user's) checks against what it
computed: for each case this script builds the FMU, writes what fmusim is given and runs it,
and keeps

- ``<case>.json``: how the FMU is built (``fmu``), the loop and role its parameters come
  from and their values as our master names them (``parameters``: ``A[2,1]``, ...),
  fmusim's options (``options``: the start values as fmusim reads them, an array's elements
  spaced, every double with 17 digits), the inputs and outputs, the step and the number of
  steps, and fmusim's exit status and log (``returncode``, ``log``);
- ``<case>_in.csv``: the input CSV as fmusim read it;
- ``<case>_out.csv``: fmusim's output CSV as it wrote it (``%.16g``).

``tests/test_fmi3_tools.py`` drives our master's ``FmuComponent`` through fmusim's calls
with those parameters and inputs and compares with ``<case>_out.csv`` everywhere; where
fmusim is found it also runs it again on the FMUs just built (the record still holds).

The inputs are held signals, so the CSV holds ``(t0, v0)`` and at each step edge
``(t_k, v_{k-1})``, ``(t_k, v_k)``: fmusim interpolates linearly between rows and takes the
row after a repeated time, so at ``t_k`` it sets ``v_k`` exactly (``docs/reference/fmi3.md``).

Usage (from the repository root; fmusim found as ``delaycomp.verify.fmusim.locate`` finds
it, ``DELAYCOMP_FMUSIM``)::

    python scripts/record_fmusim.py [--out reference/fmusim]
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from delaycomp import api
from delaycomp.fmu.native import MODEL_KINDS, build_native_fmu
from delaycomp.names import array_element
from delaycomp.paper import models as paper_models
from delaycomp.verify import fmusim

REPO = Path(__file__).resolve().parent.parent
MYLOOP = "docs/examples/myloop.toml"
H = 0.01  # the communication step of every case (myloop's and example 3.8's T/N)
TICK = 20  # myloop's T = 0.2 = 20 H: the clocked controller's ticks

#: case: (how the FMU is built, loop, role, inputs, outputs, steps, fmusim's extra options,
#: the input CSV's form: "held" (every step edge), "clock" (held, a clock column "sample"
#: 1 at each tick), "ticks" (values only at the ticks, a first row without values))
CASES: dict[str, tuple] = {
    "plant": ({"kind": "plant", "config": {"n": 3, "m": 2}}, MYLOOP, "plant",
              ["u1", "u2"], ["x1", "x2", "x3"], 300, [], "held"),
    "delay": ({"kind": "delay", "config": {"n": 3}}, MYLOOP, "meas_delay",
              ["u1", "u2", "u3"], ["y1", "y2", "y3"], 150, [], "held"),
    "controller": ({"kind": "controller", "config": {"n": 3, "m": 2}}, MYLOOP, "controller",
                   ["y1", "y2", "y3"], ["u1", "u2"], 300, [], "held"),
    "model_plant": ({"model": "example_3_8.py", "index": 0}, "example-3.8", "plant",
                    ["u"], ["x1", "x2"], 300, [], "held"),
    "model_controller": ({"model": "example_3_8.py", "index": 1}, "example-3.8",
                         "controller", ["y_x1", "y_x2"], ["u"], 300, [], "held"),
    "clocked_held": ({"kind": "controller", "config": {"n": 3, "m": 2, "clocked": True}},
                     MYLOOP, "controller", ["y1", "y2", "y3"], ["u1", "u2"], 40,
                     ["--event-mode-used"], "clock"),
    "clocked_ticks": ({"kind": "controller", "config": {"n": 3, "m": 2, "clocked": True}},
                      MYLOOP, "controller", ["y1", "y2", "y3"], ["u1", "u2"], 40,
                      ["--event-mode-used"], "ticks"),
}


def build(spec: dict, out: Path) -> Path:
    """The FMI 3.0 FMU a case's ``fmu`` entry describes, built into ``out``."""
    if "model" in spec:
        model = Path(paper_models.__file__).parent / spec["model"]
        # the index in build_native_model's list (the plant, the controller): that FMU alone
        kind = list(MODEL_KINDS)[spec["index"]]
        return build_native_fmu(kind, out / Path(spec["model"]).stem, {"model": str(model)},
                                fmi=3)
    name = "_".join([spec["kind"], *(f"{k}{v}" for k, v in spec["config"].items())])
    return build_native_fmu(spec["kind"], out / name, spec["config"], fmi=3)


def signals(count: int, steps: int) -> np.ndarray:
    """(steps + 1) x count values, one row per communication point, held over the step
    that starts there: smooth, different per channel, none exactly representable."""
    k = np.arange(steps + 1)[:, None]
    j = np.arange(count)[None, :]
    return np.sin(0.37 * (j + 1) * k * H + 0.3 * j) + 0.1 * (j - 1) + k * H / 7


def literal(value) -> str:
    """A start value as fmusim reads it: 17 digits, an array's elements spaced."""
    if isinstance(value, list):
        return " ".join(repr(float(v)) for v in value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, float) else str(value)


def as_arrays(params: dict) -> dict:
    """``A[1,1] .. A[3,3]`` (row-major, as a loop lists them) -> ``A: [9 values]``."""
    out: dict = {}
    for name, value in params.items():
        element = array_element(name)
        if element:
            out.setdefault(element[0], []).append(float(value))
        else:
            out[name] = value
    return out


def input_rows(form: str, names: list[str], values: np.ndarray) -> list[list[str]]:
    """The input CSV (header first) of a case's form, times and values with 17 digits."""
    clock = ["sample"] if form == "clock" else []
    rows = [["time", *names, *clock]]
    if form == "ticks":  # a first row without values, then values only in the ticks' rows
        rows.append(["0.0", *([""] * len(names)), "0"])
        rows[0].append("sample")
        for k, v in enumerate(values):
            cells = [repr(float(x)) for x in v] if k % TICK == 0 else [""] * len(names)
            rows.append([repr(k * H), *cells, str(int(k % TICK == 0))])
        return rows

    def row(k: int, v) -> list[str]:
        return [repr(k * H), *(repr(float(x)) for x in v)] + (
            [str(int(k % TICK == 0))] if clock else [])

    rows.append(row(0, values[0]))
    for k in range(1, len(values)):
        rows += [row(k, values[k - 1]), row(k, values[k])]
    return rows


def record(case: str, out: Path, fmu_dir: Path, cli: Path) -> dict:
    """Run one case in fmusim and write its three files into ``out``; its JSON entry."""
    spec, loop, role, inputs, outputs, steps, extra, form = CASES[case]
    parameters = dict(api.load(
        REPO / loop if loop.endswith(".toml") else loop).parameters()[role])
    options = ["--interface-type", "cs", "--stop-time", repr(steps * H),
               "--output-interval", repr(H), *extra]
    for name, value in as_arrays(parameters).items():
        options += ["--start-value", name, literal(value)]
    infile, outfile = out / f"{case}_in.csv", out / f"{case}_out.csv"
    with open(infile, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(
            input_rows(form, inputs, signals(len(inputs), steps)))
    fmu = build(spec, fmu_dir)
    proc = fmusim.simulate(fmu, options, infile, outfile, cli=cli)
    entry = {"fmu": spec, "loop": loop, "role": role, "parameters": parameters,
             "inputs": inputs, "outputs": outputs, "step": H, "steps": steps,
             "options": options, "returncode": proc.returncode,
             "log": (proc.stdout + proc.stderr).strip().splitlines()}
    (out / f"{case}.json").write_text(json.dumps(entry, indent=1) + "\n")
    return entry


def main(argv: list[str] | None = None) -> None:
    """Record every case (or those named) and print one line per case."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "reference" / "fmusim")
    parser.add_argument("cases", nargs="*", help=f"of {', '.join(CASES)} (default: all)")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.cases) - set(CASES))
    if unknown:
        parser.error(f"cases: {', '.join(unknown)} unknown (one of {', '.join(CASES)})")
    args.cases = args.cases or list(CASES)
    cli = fmusim.locate()
    version = subprocess.run([str(cli), "--version"], capture_output=True, text=True)
    print(f"fmusim: {cli} ({(version.stdout or version.stderr).strip()})")
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            entry = record(case, args.out, Path(tmp), cli)
            print(f"{case}: exit {entry['returncode']}, {len(entry['log'])} log lines")


if __name__ == "__main__":
    main()
