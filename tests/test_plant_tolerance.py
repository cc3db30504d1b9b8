"""``[plant] tolerance`` (issue 25, item 3): the relative tolerance a plant FMU with its
own variable-step solver gets at ``fmi2SetupExperiment`` (``toleranceDefined = true``).

The plant is the C test FMU ``Drive`` (``tests/cfmu``, README "Drive"): a Modelica tool's
export in miniature, hidden states ``body.phi``, ``body.w``, outputs ``sensor.phi =
-body.phi``, ``sensor.w = -body.w``, an embedded Heun-Euler 2(1) solver whose rtol and
atol are the tolerance of ``fmi2SetupExperiment`` (default 1e-4), and the statistics line
``Tolerance used : ...`` logged at ``fmi2Terminate``. In the measured coordinates
``y = -x`` the plant is ``y' = A y + B u`` with ``A = [[0, 1], [1, -0.2]]``,
``B = [[0], [-1]]``: the exact LTI loop with that ``(A, B)`` is the reference, and the
loop around the FMU differs from it by the FMU's solver error only, which the tolerance
sets (measured 2.7e-5 at the default, 9.7e-11 at 1e-10).
"""

from __future__ import annotations

import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from delaycomp.errors import ParameterError
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.system import FmuFile, lti_loop
from delaycomp.system.loopfile import read_loop
from tests.cfmu.build import build_drive

pytestmark = pytest.mark.fmu

A = np.array([[0.0, 1.0], [1.0, -0.2]])
B = np.array([[0.0], [-1.0]])
K = np.array([[3.0, 2.5]])  # u = K y: delay-free sampled loop radius 0.73
T, N, R, TAU = 0.2, 20, 0.2, 0.4
STOP = 5.0
U0 = 1.0  # the input history excites the plant (its own start state is 0)

LOOP = f"""
T = {T}
N = {N}
r = {R}
tau = {TAU}
stop_time = {STOP}
[plant]
fmu = "Drive.fmu"
states = ["sensor.phi", "sensor.w"]
inputs = ["motor.tau"]
x0 = [0, 0]
parameters = {{ "fixed.phi0" = 0 }}
[controller]
A = [[0, 1], [1, -0.2]]
B = [[0], [-1]]
K = [[3, 2.5]]
u0 = [{U0}]
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("drive")
    build_drive(out)
    (out / "drive.toml").write_text(LOOP, encoding="utf-8")
    return out


@pytest.fixture(scope="module")
def exact() -> np.ndarray:
    """The exact LTI loop in the measured coordinates (same A, B, K, delays, histories)."""
    res = run_loop(lti_loop(A, B, K, T, R, TAU, N, "compensated", [0.0, 0.0], [U0]), STOP,
                   engine="inprocess")
    assert res.success, res.message
    return res.data


def _run(folder: Path, sets=()):
    res = run_loop(read_loop(folder / "drive.toml", list(sets)), STOP)
    assert res.success, res.message
    return res


def _tolerance_used(lines) -> list[str]:
    return [line.split(":")[-1].strip() for line in lines if "Tolerance used" in line]


def test_tolerance_reaches_the_fmu_and_brings_the_loop_to_the_exact_one(folder, exact):
    default, tight = _run(folder), _run(folder, ["plant.tolerance=1e-10"])
    assert default.names == tight.names == ["plant.sensor.phi", "plant.sensor.w",
                                            "controller.u", "plant.motor.tau"]
    # the exact loop records the states and u (the plant input column is u delayed)
    err_default = np.abs(default.data[:, :3] - exact).max()
    err_tight = np.abs(tight.data[:, :3] - exact).max()
    # the FMU's solver error shows at its default (measured 2.7e-5) and all but vanishes
    # at 1e-10 (measured 9.7e-11): the tolerance reached its solver
    assert err_default > 1e-6, err_default
    assert err_tight < 1e-9, err_tight
    assert err_tight < 1e-4 * err_default
    # the FMU itself says so (its statistics at fmi2Terminate, through the child process)
    assert _tolerance_used(default.notes) == ["0.0001"], default.notes
    assert _tolerance_used(tight.notes) == ["1e-10"], tight.notes


def test_the_in_process_component_sets_it_up_too(folder):
    """Our master's FmuComponent (what the child process runs) hands the tolerance to
    fmi2SetupExperiment; without one, none is defined and the FMU takes its default."""
    from delaycomp.orchestrator.fmu import FmuComponent

    for tol, said in ((1e-7, "1e-07"), (None, "0.0001")):
        comp = FmuComponent("plant", folder / "Drive.fmu", tolerance=tol)
        try:
            comp.setup(0.0, 1.0, {})
            comp.initialize()
            comp.do_step(0.0, 0.1)
        finally:
            comp.terminate()
        assert _tolerance_used(comp.messages) == [said], comp.messages


def test_loop_file_key_and_set_give_the_plant_fmu_file_its_tolerance(folder, tmp_path):
    text = LOOP.replace('x0 = [0, 0]', 'x0 = [0, 0]\ntolerance = 1e-6')
    (tmp_path / "Drive.fmu").write_bytes((folder / "Drive.fmu").read_bytes())
    (tmp_path / "t.toml").write_text(text, encoding="utf-8")
    plant = read_loop(tmp_path / "t.toml").by_role("plant")
    assert isinstance(plant.source, FmuFile) and plant.source.tolerance == 1e-6
    plant = read_loop(tmp_path / "t.toml", ["plant.tolerance=1e-8"]).by_role("plant")
    assert plant.source.tolerance == 1e-8
    assert read_loop(folder / "drive.toml").by_role("plant").source.tolerance is None


@pytest.mark.parametrize("value", ["0", "1", "-1e-3", "2.5", "nan", "true", "[1e-3]"])
def test_bad_tolerance_is_one_line_naming_the_key_and_range(folder, value, capsys):
    from delaycomp.cli import main

    with pytest.raises(ParameterError, match=r"^plant\.tolerance = .* is not allowed: must "
                                             r"be a finite number in \(0, 1\)$"):
        read_loop(folder / "drive.toml", [f"plant.tolerance={value}"])
    assert main(["run", str(folder / "drive.toml"), "--stop-time", "0.2",
                 "--set", f"plant.tolerance={value}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plant.tolerance = " in err[0] and "(0, 1)" in err[0], err


def test_cli_set_tolerance_runs_and_the_fmu_reports_it(folder, tmp_path, capsys):
    from delaycomp.cli import main

    out = tmp_path / "d.csv"
    assert main(["run", str(folder / "drive.toml"), "--stop-time", "1", "--out", str(out),
                 "-v", "--set", "plant.tolerance=1e-8"]) == 0
    err = capsys.readouterr().err
    assert _tolerance_used(err.splitlines()) == ["1e-08"], err


def test_ssp_carries_the_tolerance_for_our_master(folder, tmp_path):
    """SSP 1.0 has no component tolerance: our archive keeps it in delaycomp's own
    annotation (dc:Component tolerance=), so the archive runs as the loop file does."""
    from delaycomp.formats import ssp

    loop = read_loop(folder / "drive.toml", ["plant.tolerance=1e-10"])
    path = ssp.pack(loop, ssp.SystemInfo("drive", "Drive", STOP), tmp_path / "d.ssp")
    with zipfile.ZipFile(path) as zf:
        assert 'tolerance="1e-10"' in zf.read("SystemStructure.ssd").decode()
    with ssp.Archive(path) as archive:
        spec = archive.system.spec
        assert spec.by_role("plant").source.tolerance == 1e-10
        res = run_loop(spec, 1.0, fmus=archive.fmus())
    direct = run_loop(loop, 1.0)
    assert np.array_equal(res.data, direct.data)
    assert _tolerance_used(res.notes) == ["1e-10"]


def test_the_container_hands_it_to_the_plant(folder, tmp_path):
    """export-loop's container forwards its fmi2SetupExperiment tolerance to the FMUs
    inside: with the plant's tolerance it reproduces our master's run at the sampling
    instants (and at the FMU's default it would not: 2.7e-5 away)."""
    from delaycomp.verify import container

    loop = read_loop(folder / "drive.toml", ["plant.tolerance=1e-10"])
    ours = run_loop(loop, 2.0)
    path = container.export_loop(loop, tmp_path / "drive-loop.fmu")
    names, times, data = container.simulate_loop(path, loop, 2.0)
    idx = np.rint(times / loop.h).astype(int)
    # every column but what the plant receives (a delay's output, a step off in the
    # container's order: container.exposed)
    assert names == ours.names[:3]
    ours = replace(ours, names=ours.names[:3], data=ours.data[:, :3])
    assert np.all(np.abs(data - ours.data[idx]) <= 1e-12 * (1 + np.abs(ours.data[idx])))


def test_masters_without_a_component_tolerance_say_so(folder, tmp_path, capsys):
    """libcosim and Ecos take no component tolerance (nor does SSP 1.0): the archive's
    plant runs at its own default there (measured: 2.7e-5 from our master's run at 1e-10,
    as at the default), and the command says so in a note."""
    from delaycomp.cli import main
    from delaycomp.verify import thirdparty

    loop = read_loop(folder / "drive.toml", ["plant.tolerance=1e-10"])
    path = thirdparty.pack_jacobi(loop, tmp_path / "d-jacobi.ssp")
    assert main(["run", str(path), "--master", "ecos", "--stop-time", "0.4"]) == 0
    err = capsys.readouterr().err
    assert ("note: --master ecos cannot hand plant.tolerance = 1e-10 to the plant FMU"
            in err), err
