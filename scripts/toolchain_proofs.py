"""One-off measurement: the native FMUs in tool chains (issue 23, item 5).

For every scenario at its defaults (the LTI ones and the model files'):

1. **OMSimulator's command line** runs the scenario's archives packed with the native FMUs
   (``delaycomp ssp SCENARIO [--jacobi] --native``, as ``delaycomp build`` ships them)
   ``--runs`` times, each in a fresh folder under
   ``env -i`` (no Python, no environment); counts the exit statuses (0 is a clean run; a
   signal or a nonzero status is a crash or a failure) and checks the last row against
   our master's run of the same archive.
2. **The FMI Compliance Checker** (``../shared/tools/fmucc``, or ``--fmucheck``) checks
   every native FMU of those archives (``-k cs -h 0.01 -s 2``, its default parameters) and
   reports its warnings and errors.
3. **valgrind** runs the C host (``fmus/native/host``) on each nonlinear scenario's native
   loop (5 s): its errors and lost blocks.
4. **Plain fmpy hosts** (``--fmpy-runs``): a fresh Python process runs each nonlinear
   scenario's loop (5 s) through fmpy and leaves by the interpreter's normal exit (the FMU
   libraries unloaded in its teardown, as any fmpy script does; ``delaycomp`` itself leaves
   with ``os._exit``), with the native FMUs and with the Python FMUs, alternately; counts
   the exit statuses (0 with the run's result printed is a clean run).

Prints one markdown table per part. OMSimulator is found as ``delaycomp.verify.omsimulator``
finds it (``DELAYCOMP_OMSIMULATOR``). Usage::

    python scripts/toolchain_proofs.py --runs 20
"""

from __future__ import annotations

import argparse
import collections
import csv
import re
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from delaycomp.fmu.host import compile_host, host_argv, unpack
from delaycomp.fmu.native import native_archive
from delaycomp.fmu.twins import native_fmus
from delaycomp.formats.ssp import Archive, loop_system, pack
from delaycomp.orchestrator.simulate import run_loop, stop_ticks
from delaycomp.paper import scenarios
from delaycomp.verify.omsimulator import locate
from delaycomp.verify.thirdparty import pack_jacobi

REPO = Path(__file__).resolve().parent.parent
FMUCHECK = REPO.parent / "shared" / "tools" / "fmucc" / "fmuCheck.linux64"
NONLINEAR = ("example-2.4", "example-3.8", "corollary-4.1", "proposition-4.2")


def _status(code: int) -> str:
    return f"signal {-code}" if code < 0 else f"exit {code}"


def oms_runs(work: Path, runs: int) -> tuple[list[str], dict[str, Path]]:
    cli = locate().cli
    rows, archives = [], {}
    for name in scenarios.SCENARIOS:
        sc = scenarios.get(name)
        loop = sc.make(sc.resolve([]))
        stop = stop_ticks(loop.stop_time, loop.T, loop.N) * loop.h
        for label, python in ((name, pack(*loop_system(loop), work / f"{name}-py.ssp")),
                              (f"{name}-jacobi", pack_jacobi(loop, work /
                                                             f"{name}-jacobi-py.ssp"))):
            archive = native_archive(python, work / f"{label}.ssp")
            archives[label] = archive
            rows.append(_oms_row(cli, label, archive, stop, runs, work))
    return rows, archives


def _oms_row(cli, name: str, archive: Path, stop: float, runs: int, work: Path) -> str:
    """One archive ``runs`` times in OMSimulator's command line: a table row."""
    with Archive(archive) as opened:
        ours = run_loop(opened.system.spec, stop, fmus=opened.fmus())
    statuses, worst = collections.Counter(), 0.0
    for _ in range(runs):
        folder = Path(tempfile.mkdtemp(prefix="oms-", dir=work))
        result = folder / "result.csv"
        proc = subprocess.run(["env", "-i", str(cli), f"--stopTime={stop!r}",
                               f"--resultFile={result}", str(archive)],
                              cwd=folder, capture_output=True, text=True, timeout=600)
        bad = "error:" in proc.stdout + proc.stderr
        statuses[_status(proc.returncode) + (" (errors logged)" if bad else "")] += 1
        if proc.returncode == 0 and result.exists():
            with open(result, newline="", encoding="utf-8") as fh:
                table = list(csv.reader(fh, skipinitialspace=True))
            header, last = table[0], table[-1]
            for j, signal in enumerate(ours.names):
                col = next(i for i, h in enumerate(header)
                           if h.endswith("." + signal))
                scale = max(1.0, float(np.max(np.abs(ours.data[:, j]))))
                worst = max(worst, abs(float(last[col]) - ours.data[-1, j]) / scale)
        shutil.rmtree(folder, ignore_errors=True)
    return (f"| {name} | {runs} | "
            f"{', '.join(f'{k}: {v}' for k, v in sorted(statuses.items()))} | "
            f"{worst:.2g} |")


def fmucheck(work: Path, archives: dict[str, Path], tool: Path) -> list[str]:
    rows, seen = [], set()
    for archive in archives.values():
        with zipfile.ZipFile(archive) as zf:
            for item in zf.namelist():
                if not item.endswith(".fmu") or Path(item).name in seen:
                    continue
                seen.add(Path(item).name)
                fmu = work / "fmucc" / Path(item).name
                fmu.parent.mkdir(exist_ok=True)
                fmu.write_bytes(zf.read(item))
                log = fmu.with_suffix(".log")
                proc = subprocess.run([str(tool), "-k", "cs", "-h", "0.01", "-s", "2", "-l",
                                       "3", "-e", str(log), "-o", str(fmu.with_suffix(".csv")),
                                       str(fmu)], capture_output=True, text=True, timeout=300)
                text = log.read_text(encoding="utf-8", errors="replace")
                found = {kind: int(n) for n, kind in
                         re.findall(r"(\d+) (Warning|Error)\(s\)", text)}
                warnings = sorted({m.strip() for m in re.findall(
                    r"\[WARNING\]\[FMUCHK\](.*)", text)})
                rows.append(f"| {fmu.name} | {_status(proc.returncode)} | "
                            f"{found.get('Warning', '?')} | {found.get('Error', '?')} | "
                            f"{'; '.join(warnings) or '-'} |")
    return rows


def valgrind(work: Path) -> list[str]:
    exe = compile_host(work / "host")
    rows = []
    for name in NONLINEAR:
        sc = scenarios.get(name)
        loop = sc.make(sc.resolve([]))
        stop = stop_ticks(5.0, loop.T, loop.N) * loop.h
        dirs = unpack(native_fmus(loop, work / "native"), work / "unpacked" / name)
        proc = subprocess.run(["valgrind", "--leak-check=full", "--error-exitcode=9",
                               *host_argv(exe, loop, stop, dirs)],
                              capture_output=True, text=True, timeout=900)
        errors = re.search(r"ERROR SUMMARY: (\d+) errors", proc.stderr)
        freed = "All heap blocks were freed" in proc.stderr
        lost = re.search(r"definitely lost: ([\d,]+) bytes", proc.stderr)
        rows.append(f"| {name} | {len(proc.stdout.splitlines()) - 1} | "
                    f"{errors.group(1) if errors else '?'} | "
                    f"{'all freed' if freed else (lost.group(1) + ' B lost') if lost else '?'} "
                    f"| {_status(proc.returncode)} |")
    return rows


#: a plain fmpy host: the loop through fmpy, then the interpreter's normal exit
FMPY_CHILD = """
import sys
from pathlib import Path
from delaycomp.paper import scenarios
from delaycomp.fmu.native import native_fmus
from delaycomp.orchestrator.simulate import run_loop, stop_ticks
name, kind, folder = sys.argv[1:4]
sc = scenarios.get(name)
loop = sc.make(sc.resolve([]))
stop = stop_ticks(5.0, loop.T, loop.N) * loop.h
fmus = native_fmus(loop, Path(folder) / "native") if kind == "native" else None
res = run_loop(loop, stop, Path(folder) / "python", fmus=fmus)
print("ok" if res.success else "failed: " + res.message)
"""


def fmpy_runs(work: Path, runs: int) -> list[str]:
    import sys

    folder = work / "fmpy"
    rows = []
    for name in NONLINEAR:
        counts = {"native": collections.Counter(), "python": collections.Counter()}
        for _ in range(runs):
            for kind in counts:
                proc = subprocess.run([sys.executable, "-c", FMPY_CHILD, name, kind,
                                       str(folder)], capture_output=True, text=True,
                                      timeout=600)
                clean = proc.returncode == 0 and proc.stdout.strip() == "ok"
                counts[kind]["clean" if clean else _status(proc.returncode)
                             + (f" ({proc.stderr.strip().splitlines()[-1]})"
                                if proc.stderr.strip() else "")] += 1
        rows.append(f"| {name} | {runs} | "
                    + " | ".join(", ".join(f"{k}: {v}" for k, v in sorted(c.items()))
                                 for c in counts.values()) + " |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--fmucheck", type=Path, default=FMUCHECK)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--fmpy-runs", type=int, default=0,
                    help="plain fmpy host processes per scenario and FMU kind (part 4)")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="delaycomp-proofs-"))
    work.mkdir(parents=True, exist_ok=True)
    oms, archives = oms_runs(work, args.runs)
    print("| scenario (native archive) | runs | OMSimulator's exit statuses | last row vs "
          "our master |\n|---|---|---|---|")
    print("\n".join(oms))
    print("\n| native FMU | fmuCheck | warnings | errors | what |\n|---|---|---|---|---|")
    print("\n".join(fmucheck(work, archives, args.fmucheck)))
    print("\n| scenario (C host, 5 s) | rows | valgrind errors | heap | status |\n"
          "|---|---|---|---|---|")
    print("\n".join(valgrind(work)))
    if args.fmpy_runs:
        print("\n| scenario (plain fmpy host, 5 s) | runs | native FMUs | Python FMUs |\n"
              "|---|---|---|---|")
        print("\n".join(fmpy_runs(work, args.fmpy_runs)))


if __name__ == "__main__":
    main()
