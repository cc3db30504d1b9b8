"""A network channel in the hosts (issue 29, item 3, slice b): ``ssp`` (and ``--jacobi``),
``export-loop`` (FMI 2 and 3), ``build LOOP.toml``.

The loop: the double integrator of ``tests/test_loop_channel.py`` with a jittered, lossy
channel on the measurement side (uniform jitter 0.35 > T = 0.2, bernoulli 0.3, seed 11)
and a measured trace on the input side (a lost packet among them). Every host runs the
same native C channel with the same doubles as ``run`` (the same packets sent at the same
steps, so the same draws): the trajectories are compared bit for bit. The Jacobi and the
container variants move every packet's delay by one base step ``h`` (least delay, trace,
timeout); a packet is then seen one step earlier (later) unless its drawn delay over ``h``
lies within the rounding of ``delay +- h`` (some 1e-16 relative) of the edge of
``grid.steps_up``'s band round an integer: an event of probability ~1e-15 per packet, so
bit for bit is what is asserted here too.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from delaycomp.cli import main
from delaycomp.errors import ParameterError
from delaycomp.system.jacobi import CompensationError, jacobi_variant, shifted_delay
from delaycomp.verify import omsimulator, thirdparty

from .test_loop_channel import _loop, _toml

pytestmark = pytest.mark.fmu

MEAS = {"distribution": "uniform", "jitter": 0.35, "loss_model": "bernoulli", "loss": 0.3,
        "seed": 11}
TRACE = [0.4, 0.45, float("nan"), 0.62, 0.4, 0.5, 0.81, 0.43]


@pytest.fixture(scope="module")
def loop_file(tmp_path_factory):
    """The loop file, its trace, and ``run``'s CSV (native channel, our master)."""
    folder = tmp_path_factory.mktemp("net")
    (folder / "trace.csv").write_text(
        "delay\n" + "\n".join("nan" if d != d else repr(d) for d in TRACE) + "\n")
    path = _toml(folder / "net.toml", meas_delay=MEAS,
                 input_delay={"distribution": "trace", "trace": "trace.csv"})
    assert main(["run", str(path), "--out", str(folder / "run.csv")]) == 0
    return path, np.loadtxt(folder / "run.csv", delimiter=",", skiprows=1)


def _csv(path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1)


def test_ssp_carries_the_channels_and_their_parameters(loop_file, tmp_path):
    path, _ = loop_file
    assert main(["ssp", str(path), "--out", str(tmp_path / "n.ssp")]) == 0
    import zipfile

    with zipfile.ZipFile(tmp_path / "n.ssp") as zf:
        names = zf.namelist()
        meas = zf.read("resources/meas_delay.ssv").decode()
        inp = zf.read("resources/input_delay.ssv").decode()
    assert "resources/DelaycompChannel_n2.fmu" in names
    assert "resources/DelaycompChannel_L8_n1.fmu" in names
    # Strings as their Integer twins (OMSimulator sets no String), the seed an Integer
    assert 'name="distribution_index"' in meas and 'name="seed"' in meas
    assert '<ssv:Integer value="11"/>' in meas and 'name="distribution"' not in meas
    assert all(f'name="trace[{i}]"' in inp for i in range(1, 9))


@pytest.mark.parametrize("fmus", ["--native", "--python"])
def test_ssp_in_our_master_is_run_bit_for_bit(loop_file, tmp_path, fmus):
    path, ours = loop_file
    archive = tmp_path / "n.ssp"
    assert main(["ssp", str(path), fmus, "--out", str(archive)]) == 0
    if fmus == "--python":  # the Python channel's own run is the reference
        assert main(["run", str(path), "--python", "--out", str(tmp_path / "py.csv")]) == 0
        ours = _csv(tmp_path / "py.csv")
    assert main(["run", str(archive), "--out", str(tmp_path / "ssp.csv")]) == 0
    assert np.array_equal(_csv(tmp_path / "ssp.csv"), ours)


def test_omsimulator_command_line_runs_the_archive_bit_for_bit(oms, loop_file, tmp_path):
    """`OMSimulator --stopTime --resultFile file.ssp`: the same native C, the same
    doubles, but its result CSV prints each value in decimal to about 12 significant
    digits, so it is held to ``1e-11 |ours| + 1e-12`` as the shipped archives are
    (``tests/test_omsimulator.py``); the Python API's run below is bit for bit."""
    path, ours = loop_file
    archive = tmp_path / "n.ssp"
    assert main(["ssp", str(path), "--out", str(archive)]) == 0
    result = tmp_path / "result.csv"
    argv, env = omsimulator.cli_command(archive, 6.0, result)
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)
    log = proc.stdout + proc.stderr
    assert not [ln for ln in log.splitlines() if ln.startswith("error:")], log[-2000:]
    loop = _loop()
    times, data = omsimulator.read_cli_result(result, "dbl", loop.recorded)
    assert np.array_equal(times, ours[:, 0]) or np.allclose(times, ours[:, 0], rtol=0,
                                                            atol=1e-9)
    assert np.all(np.abs(data - ours[:, 1:]) <= 1e-11 * np.abs(ours[:, 1:]) + 1e-12)


@pytest.mark.parametrize("master", [*thirdparty.MASTERS, "omsimulator", "delaycomp"])
def test_the_jacobi_archive_in_each_master_is_run_bit_for_bit(loop_file, tmp_path, master,
                                                              oms):
    path, ours = loop_file
    archive = tmp_path / "j.ssp"
    assert main(["ssp", str(path), "--jacobi", "--out", str(archive)]) == 0
    out = tmp_path / f"{master}.csv"
    assert main(["run", str(archive), "--master", master, "--out", str(out)]) == 0
    assert np.array_equal(_csv(out), ours), master


def test_the_jacobi_variant_shortens_every_packet_by_h():
    params = {"delay": 0.36, "trace[1]": 0.4, "trace[2]": -1.0, "max_delay": 0.7, "seed": 3}
    assert shifted_delay(params, -0.01) == {"delay": 0.36 - 0.01, "trace[1]": 0.4 - 0.01,
                                            "max_delay": 0.7 - 0.01}
    variant = jacobi_variant(_loop(meas_delay=MEAS, input_delay={"jitter": 0.1,
                                                                 "distribution": "uniform"}))
    assert variant.by_role("meas_delay").parameters["delay"] == 0.36 - 0.01
    assert variant.by_role("input_delay").parameters["delay"] == 0.4  # as it is


def test_the_jacobi_variant_refuses_a_channel_with_delay_0():
    loop = _loop(input_delay={"delay": 0.0, "distribution": "uniform", "jitter": 0.1})
    with pytest.raises(CompensationError, match="input_delay: a channel with delay 0"):
        jacobi_variant(loop)


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_export_loop_is_run_bit_for_bit_at_the_sampling_instants(loop_file, tmp_path, fmi):
    from fmpy import simulate_fmu

    path, ours = loop_file
    out = tmp_path / "n.fmu"
    assert main(["export-loop", str(path), "--fmi", fmi, "--out", str(out)]) == 0
    res = simulate_fmu(str(out), stop_time=6.0, output_interval=0.2)
    at = ours[::20]
    assert np.allclose(res["time"], at[:, 0], rtol=0, atol=1e-9)
    for name, col in (("x1", 1), ("x2", 2), ("u", 3)):
        assert np.array_equal(np.asarray(res[name]), at[:, col]), name


def test_build_writes_the_channel_fmus(loop_file, tmp_path):
    from fmpy import read_model_description

    path, _ = loop_file
    assert main(["build", str(path), "--out", str(tmp_path / "b")]) == 0
    for role, n in (("meas_delay", "y2"), ("input_delay", "stamp")):
        md = read_model_description(str(tmp_path / "b" / f"dbl_{role}.fmu"))
        names = {v.name for v in md.modelVariables}
        assert {"stamp", "seed", n} <= names, role
    assert "trace[8]" in {v.name for v in read_model_description(
        str(tmp_path / "b" / "dbl_input_delay.fmu")).modelVariables}


def test_api_to_ssp_takes_a_channel(tmp_path):
    from delaycomp import api

    try:
        api.to_ssp(_loop(meas_delay=MEAS), tmp_path / "l.ssp", fmus="python")
    except ParameterError as exc:  # pragma: no cover - the refusal is gone
        pytest.fail(str(exc))
    assert (tmp_path / "l.ssp").is_file()
