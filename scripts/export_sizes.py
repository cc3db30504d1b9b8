"""The Cortex-M4 size of each shipped scenario's exported controller (issue 33, item 3).

For every scenario at its defaults, ``delaycomp export-c`` writes the controller; it is
compiled with ``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfloat-abi=hard
-mfpu=fpv4-sp-d16 -std=c99 -Wall -Wextra -pedantic -Werror`` at ``-O2`` and ``-Os``, and
``arm-none-eabi-size`` gives the object's code and constants (``text``: the functions and
the loop's tables) and writable data (``data``, ``bss``: none, the controller has no global
state); ``sizeof(NAME_state)`` is the RAM of one controller. The object's size leaves out
what the linker adds from libgcc (the Cortex-M4's FPU is single precision: doubles are
computed by libgcc's soft-float routines) and libm (the model's ``sin``, ``exp``, ...).

    python scripts/export_sizes.py            # a Markdown table (docs/howto/microcontroller.md)
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

from delaycomp.formats.exportc import export_c
from delaycomp.paper import scenarios

CC = ["arm-none-eabi-gcc", "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard",
      "-mfpu=fpv4-sp-d16", "-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror"]


def sizes(loop, tmp: Path, opt: str) -> tuple[int, int, int, int]:
    """(text, data, bss, sizeof state) of the exported controller of ``loop``."""
    export_c(loop, tmp, "ctl")
    obj = tmp / "ctl.o"
    subprocess.run([*CC, opt, "-c", str(tmp / "ctl.c"), "-o", str(obj)], check=True)
    text, data, bss = (int(v) for v in subprocess.run(
        ["arm-none-eabi-size", str(obj)], capture_output=True, text=True,
        check=True).stdout.splitlines()[1].split()[:3])
    probe = tmp / "probe.c"
    probe.write_text('#include "ctl.h"\nchar ctl_state_size[sizeof(ctl_state)];\n')
    subprocess.run([*CC, "-c", "-I", str(tmp), str(probe), "-o", str(tmp / "probe.o")],
                   check=True)
    nm = subprocess.run(["arm-none-eabi-nm", "-S", str(tmp / "probe.o")],
                        capture_output=True, text=True, check=True).stdout
    state = next(int(line.split()[1], 16) for line in nm.splitlines()
                 if line.endswith("ctl_state_size"))
    return text, data, bss, state


def main() -> int:
    version = subprocess.run(["arm-none-eabi-gcc", "-dumpversion"], capture_output=True,
                             text=True, check=True).stdout.strip()
    print(f"arm-none-eabi-gcc {version}, -mcpu=cortex-m4 -mthumb -mfloat-abi=hard "
          "-mfpu=fpv4-sp-d16; bytes\n")
    print("| scenario | controller | code -O2 | code -Os | data + bss | state |")
    print("|---|---|---|---|---|---|")
    for name in scenarios.SCENARIOS:
        sc = scenarios.get(name)
        variants = [[]]
        if any(p.name == "predictor" for p in sc.params):  # a model: its DOP853 too
            variants.append(["predictor=numerical"])
        for sets in variants:
            loop = sc.make(sc.resolve(sets))
            with tempfile.TemporaryDirectory() as tmp:
                text2, data, bss, state = sizes(loop, Path(tmp), "-O2")
                texts, *_ = sizes(loop, Path(tmp), "-Os")
            label = name + "".join(f", {s}" for s in sets)
            print(f"| {label} | {_what(loop)} | {text2} | {texts} | {data + bss} | {state} |")
    return 0


def _what(loop) -> str:
    inst = loop.by_role("controller")
    kind, config = inst.source.build_key()
    if kind == "controller":
        return f"LTI, mode {inst.parameters.get('mode', 'compensated')}"
    model = Path(config["model"]).stem
    return f"model {model}, predictor {inst.parameters.get('predictor', 'closed')}"


if __name__ == "__main__":
    sys.exit(main())
