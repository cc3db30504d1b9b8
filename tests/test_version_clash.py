"""Two FMUs bundling different delaycomp versions, in one process: the second refuses.

pythonfmu FMUs share the host's interpreter and ``sys.modules``: the FMU loaded second
would run the first one's ``delaycomp``. It must say so (logged with status error, naming
both versions), refuse to initialize and to step, and the host must survive and free it.
The instantiation runs in a fresh process, since ``sys.modules`` is shared.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from delaycomp.fmu.build import FMU_ROOT, PACKAGE_DIR
from delaycomp.orchestrator import __file__ as orchestrator_init

pytestmark = pytest.mark.fmu


def build_with_version(tmp_path, version: str):
    """The delay FMU built from a copy of the sources whose ``__version__`` is ``version``."""
    src = tmp_path / "src"
    shutil.copytree(PACKAGE_DIR, src / "delaycomp",
                    ignore=shutil.ignore_patterns("__pycache__"))
    # the repository's fmus/ and orchestrator/ install as delaycomp.fmus, .orchestrator
    for folder in (FMU_ROOT, Path(orchestrator_init).parent):
        shutil.copytree(folder, src / "delaycomp" / folder.name,
                        ignore=shutil.ignore_patterns("__pycache__"))
    leaf = src / "delaycomp" / "version.py"  # where the version lives
    text = leaf.read_text(encoding="utf-8")
    leaf.write_text(text.replace('__version__ = "', f'__version__ = "{version}" #'),
                    encoding="utf-8")
    out = tmp_path / "other"
    code = ("import delaycomp, delaycomp.fmu.build as b\n"
            f"assert delaycomp.__version__ == {version!r}, delaycomp.__file__\n"
            f"print(b.build_fmu('delay', {str(out)!r}))\n")
    env = dict(os.environ, PYTHONPATH=str(src))
    proc = subprocess.run([sys.executable, "-c", code], cwd=src, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip().splitlines()[-1]


def test_second_fmu_with_another_bundled_version_is_refused(fmu_dir, tmp_path):
    other = build_with_version(tmp_path, "0.0.1-other")
    plant = fmu_dir / "DelaycompPlantLTI.fmu"
    code = textwrap.dedent(f'''
        from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused
        plant = FmuComponent("plant", {str(plant)!r})
        delay = FmuComponent("delay", {other!r})
        try:
            plant.setup(0.0, 1.0, {{}})
            plant.initialize()
            delay.setup(0.0, 1.0, {{}})
            try:
                delay.initialize()
            except FmuRefused as exc:
                print("REFUSED:", exc)
            else:
                print("ACCEPTED")
            from fmpy.fmi1 import FMICallException
            try:
                delay.do_step(0.0, 0.1)
            except FMICallException as exc:
                print("STEP STATUS:", exc.status)
            plant.do_step(0.0, 0.1)
            print("PLANT STILL STEPS")
        finally:
            delay.terminate()
            plant.terminate()
        print("FREED")
    ''')
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "REFUSED: version clash: this FMU bundles delaycomp '0.0.1-other', but " \
           "delaycomp '0.1.0'" in out, out
    assert "STEP STATUS: 2" in out  # fmi2Discard: docs/explanation/reliability.md
    assert "PLANT STILL STEPS" in out
    assert out.strip().endswith("FREED")


def test_same_version_fmus_share_one_process(fmu_dir, tmp_path):
    """The control case: the default FMUs (one version) load side by side.

    Both children leave through the interpreter's normal exit. Before issue 30, item 10
    they left with ``os._exit``: the teardown aborted them with "corrupted double-linked
    list" in 7 of 28 runs (pythonfmu's runtime library wrote into a freed block at exit,
    ``delaycomp.fmu.runtime``)."""
    code = textwrap.dedent(f'''
        from delaycomp.orchestrator.fmu import FmuComponent
        comps = [FmuComponent(p.stem, p) for p in
                 sorted(__import__("pathlib").Path({str(fmu_dir)!r}).glob("Delaycomp*.fmu"))]
        for c in comps:
            c.setup(0.0, 1.0, {{}})
            c.initialize()
        for c in comps:
            c.terminate()
        print(len(comps))
    ''')
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip()) >= 3
