"""Compile the C test plant FMU (``Oscillator``) with the system C compiler.

The FMU is a zip of ``modelDescription.xml``, ``binaries/linux64/Oscillator.so`` and its
``sources/``; the FMI 2.0 headers come from the installed fmpy (``fmpy/c-code``). Nothing
here uses pythonfmu: this is the "FMU nobody here generated with pythonfmu" of issue 14.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
MODEL = "Oscillator"


class CompilerMissing(RuntimeError):
    """No C compiler on PATH (the tests that need this FMU fail with this message)."""


#: how ``build_oscillator``'s plant may misbehave (``oscillator.c``'s MISBEHAVE)
MISBEHAVIOURS = {"hang": 1, "exit": 2, "crash": 3}


def _pack(out_dir: Path, name: str, model: str, source: str, description: str,
          flags: list[str]) -> Path:
    """Compile ``source`` (beside this file) with ``flags`` into ``binaries/linux64/
    <model>.so`` and pack it with the modelDescription text ``description``, the source and
    README.md into ``out_dir/name``; return its path."""
    import fmpy

    if not sys.platform.startswith("linux"):
        raise CompilerMissing(f"the C test FMU is built for linux64 only, not {sys.platform}")
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise CompilerMissing("no C compiler (gcc or cc) on PATH: the C test FMU needs one")
    headers = Path(fmpy.__file__).resolve().parent / "c-code"
    out_dir = Path(out_dir)
    work = out_dir / f"{Path(name).stem}-build"
    (work / "binaries" / "linux64").mkdir(parents=True, exist_ok=True)
    lib = work / "binaries" / "linux64" / f"{model}.so"
    proc = subprocess.run([cc, "-std=gnu99", "-O2", "-Wall", "-Wextra", "-Werror", "-shared",
                           "-fPIC", f"-I{headers}", "-o", str(lib), *flags,
                           str(HERE / source), "-lm"], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling the C test FMU failed:\n{proc.stderr.strip()}")
    target = out_dir / name
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("modelDescription.xml", description)
        zf.write(lib, f"binaries/linux64/{model}.so")
        zf.write(HERE / source, f"sources/{source}")
        zf.write(HERE / "README.md", "documentation/README.md")
    shutil.rmtree(work)
    return target


def build_oscillator(out_dir: Path, name: str = f"{MODEL}.fmu",
                     broken_after: float | None = None, misbehave: str | None = None,
                     after: float = 0.0) -> Path:
    """Compile ``oscillator.c`` and pack the FMU into ``out_dir``; return its path.
    ``broken_after``: a plant that breaks down, its ``position`` NaN from that time on
    (its state and every FMI status as before: only its output is broken).
    ``misbehave`` (``MISBEHAVIOURS``): at its first ``fmi2DoStep`` from ``after`` on,
    the plant never returns (``hang``), calls ``exit(0)`` (``exit``) or raises SIGSEGV
    (``crash``)."""
    flags = [*([] if broken_after is None else [f"-DBROKEN_AFTER={broken_after!r}"]),
             *([] if misbehave is None else [f"-DMISBEHAVE={MISBEHAVIOURS[misbehave]}",
                                             f"-DMISBEHAVE_AFTER={float(after)!r}"])]
    return _pack(out_dir, name, MODEL, "oscillator.c",
                 (HERE / "modelDescription.xml").read_text(encoding="utf-8"), flags)


DRIVE = "Drive"


def build_drive(out_dir: Path, name: str = f"{DRIVE}.fmu", directional: bool = True,
                co_simulation: bool = True, model_exchange: bool = True) -> Path:
    """Compile ``drive.c`` (a plant FMU that behaves like a Modelica tool's export: hidden
    continuous states, sensor outputs, its own variable-step solver; README.md) and pack
    it into ``out_dir``; return its path. ``directional = False``: an FMU that provides no
    directional derivatives (its modelDescription says so and the call fails).
    ``co_simulation`` / ``model_exchange``: which interfaces its modelDescription declares.
    """
    xml = (HERE / "drive.xml").read_text(encoding="utf-8")
    if not directional:
        xml = xml.replace('providesDirectionalDerivative="true"',
                          'providesDirectionalDerivative="false"')
    for keep, tag in ((co_simulation, "CoSimulation"), (model_exchange, "ModelExchange")):
        if not keep:
            start = xml.index(f"<{tag} ")
            xml = xml[:start] + xml[xml.index("/>", start) + 2:]
    return _pack(out_dir, name, DRIVE, "drive.c", xml,
                 [] if directional else ["-DNO_DIRECTIONAL"])


VANDERPOL = "VanDerPol"


def build_vanderpol(out_dir: Path, name: str = f"{VANDERPOL}.fmu",
                    directional: bool = True) -> Path:
    """Compile ``vanderpol.c`` (a Van der Pol oscillator with an input, shaped like the
    modelica/Reference-FMUs' ``VanDerPol``: its continuous states are its outputs,
    ``initial="exact"`` with start values, settable before initialization, listed with
    ``dependencies=""``; README.md) and pack it into ``out_dir``; return its path.
    ``directional = False``: its modelDescription declares no directional derivatives
    (``providesDirectionalDerivative="false"``), so a master uses differences."""
    xml = (HERE / "vanderpol.xml").read_text(encoding="utf-8")
    if not directional:
        xml = xml.replace('providesDirectionalDerivative="true"',
                          'providesDirectionalDerivative="false"')
    return _pack(out_dir, name, VANDERPOL, "vanderpol.c", xml, [])
