"""User models as FMUs: build --model, self-containment, two models in one process."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper.scenarios import model_loop

pytestmark = pytest.mark.fmu

MODEL = textwrap.dedent('''\
    """x' = {gain} u with the dead-beat ZOH law u = -x / ({gain} T)."""
    import numpy as np

    STATES = ("x",)
    INPUTS = ("u",)
    CONTROL = "zoh"

    def f(x, u, p):
        return np.array([{gain} * u[0]])

    def k(x, p):
        return np.array([-x[0] / ({gain} * p["T"])])
    ''')


def write_model(folder, gain):
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "plant_model.py"  # the same file name for both models on purpose
    path.write_text(MODEL.format(gain=gain), encoding="utf-8")
    return path


def test_two_models_with_the_same_file_name_run_side_by_side(tmp_path):
    """Each FMU bundles its model under a name unique to its content: no sys.modules clash.

    If the second loop ran the first model's code (x' = u with the gain 1/(2T) law), x
    would halve every period instead of reaching zero.
    """
    a = write_model(tmp_path / "a", 1.0)
    b = write_model(tmp_path / "b", 2.0)
    fmus = tmp_path / "fmus"
    T, r, N = 1.0, 0.5, 10
    for path in (a, b, a):
        # u0 != 0 makes the initial function inconsistent with the input history, so the
        # first prediction is not exact (errata) and the dead-beat time is the bound
        res = run_loop(model_loop(path, T, r, 0.0, N, [1.0], [0.5]), 4.0, fmus)
        assert res.success, res.message
        x = res.column("plant.x")
        # dead-beat in 1T without delay, so zero from (1 + ceil(r/T)) T = 2T on
        assert np.abs(x[2 * N:]).max() < 1e-12
        assert abs(x[2 * N - 1]) > 1e-3


def test_build_model_cli_writes_valid_fmus(tmp_path):
    model = write_model(tmp_path / "m", 1.5)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "delaycomp.cli", "build", "--model", str(model),
                           "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    built = sorted(p.name for p in out.glob("*.fmu"))
    assert len(built) == 3  # plant, controller, one delay (n = m = 1)
    assert any(n.startswith("DelaycompPlant_plant_model_") for n in built)
    assert any(n.startswith("DelaycompController_plant_model_") for n in built)
    for name in built:
        assert validate_fmu(str(out / name)) == [], name


def test_bad_model_file_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("STATES = ('x',)\nINPUTS = ('u',)\nCONTROL = 'sometimes'\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "delaycomp.cli", "build", "--model", str(bad),
                           "--out", str(tmp_path / "o")], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "CONTROL" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_model_fmus_run_in_a_fresh_process_elsewhere(tmp_path):
    model = write_model(tmp_path / "m", 1.0)
    fmus = tmp_path / "fmus"
    run_loop(model_loop(model, 1.0, 0.0, 0.0, 2, [1.0], [0.0]), 1.0, fmus)  # builds them
    plant = next(fmus.glob("DelaycompPlant_*.fmu"))
    code = textwrap.dedent(f'''\
        from fmpy import simulate_fmu
        import numpy as np
        res = simulate_fmu({str(plant)!r}, stop_time=1.0, output_interval=0.5,
                           start_values={{"x0[1]": 2.0}},
                           input=np.array([(0.0, 1.0)], dtype=[("time", float), ("u", float)]))
        import delaycomp
        assert "/resources/delaycomp/" in delaycomp.__file__.replace("\\\\", "/")
        print(res["x"][-1])
        ''')
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert float(proc.stdout.strip()) == pytest.approx(3.0, abs=1e-9)


def test_repeated_instantiation_keeps_the_slave_module_intact(tmp_path):
    """pythonfmu 0.7 drops a reference to the slave module's dict per instantiation; the
    pins in delaycomp.fmu.slave must keep every slave module whole (see its docstring)."""
    import sys

    from delaycomp.orchestrator.fmu import FmuComponent

    model = write_model(tmp_path / "m", 1.0)
    fmus = tmp_path / "fmus"
    run_loop(model_loop(model, 1.0, 0.0, 0.0, 2, [1.0], [0.0]), 1.0, fmus)
    for path in sorted(fmus.glob("*.fmu")):
        for _ in range(25):
            comp = FmuComponent("c", path)
            try:
                comp.setup(0.0, 1.0, {})
                comp.initialize()
            finally:
                comp.terminate()
    slaves = [m for name, m in sys.modules.items()
              if name.startswith(("delaycomp_model_plant_", "delaycomp_model_controller_",
                                "delaycomp_delay"))]
    assert slaves
    for module in slaves:
        assert module.__name__.startswith("delaycomp_")
        assert sys.getrefcount(vars(module)) >= 3  # the module, the pins, the call


def test_documented_model_example_builds_and_is_deadbeat(tmp_path):
    """The model module shown on the model-file page works as documented."""
    from .conftest import REPO

    text = (REPO / "docs" / "reference" / "model-files.md").read_text(encoding="utf-8")
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "readme_model.py"
    path.write_text(code, encoding="utf-8")
    T, N = 1.0, 10
    res = run_loop(model_loop(path, T, 0.5, 1.0, N, [1.0, -1.0], [0.3],
                              params={"gain": 2.0}), 7.0, tmp_path / "fmus")
    assert res.success, res.message
    x = np.abs(res.data[:, :2]).max(axis=1)
    # dead-beat in 2T without delay; l = 1, ceil(r/T) = 1: zero from 4T
    assert x[4 * N:].max() < 1e-12 and x[4 * N - 1] > 1e-6
