"""The whole loop as one container FMU (``delaycomp export-loop``, issue 4 item 6)."""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.verify import check, container

from .conftest import REPO
from .tiers import tiered

pytestmark = pytest.mark.fmu

#: the zero-order-hold scenarios (exact) and one continuous one (first order in h)
CASES = ["example-3.6/fig2", "example-3.6/fig3", "example-3.8/delayed", "corollary-3.7/n2",
         "proposition-4.2/nodelay_r", "example-2.4/sparse"]


def _spec(c):
    sc = scenarios.get(c.scenario)
    return sc.make(sc.resolve(list(c.sets)))


def cli(*args):
    return subprocess.run([sys.executable, "-m", "delaycomp.cli", *args], capture_output=True,
                          text=True, cwd=REPO, timeout=600, env=dict(os.environ))


@pytest.mark.parametrize("case_id", CASES)
def test_container_matches_the_reference_at_the_sampling_instants(case_id, tmp_path):
    """fmpy.simulate_fmu(container, output_interval=T) against the reference trace at
    t0 + iT with the tolerances of delaycomp.verify.check (zero-order hold: 1e-9 (1 + |ref|),
    round-off; continuous input: 2 % of the range, the O(h) of holding u over h). And,
    stronger, against our master's loop at the same instants to 1e-9 (1 + |value|): every
    FMU gets what it gets in our master, so only round-off separates them."""
    c = check.case(case_id)
    spec = _spec(c)
    path = container.export_loop(spec, tmp_path / "loop.fmu")
    names, times, data = container._simulate_in_child(path, c)
    assert np.allclose(times, np.arange(len(times)) * spec.T, rtol=0, atol=1e-9)
    cmp = check.compare(c, names, times, data, ref_stride=spec.N)
    assert cmp.passed, (cmp.max_error, cmp.tolerance)
    ours = run_loop(spec, c.stop_time())
    cols = [ours.names.index(n) for n in names]
    loop = ours.data[::spec.N][:, cols]
    assert loop.shape == data.shape
    assert np.all(np.abs(data - loop) <= 1e-9 * (1 + np.abs(loop)))


def test_export_loop_cli_writes_an_fmu_that_fmpy_validates(tmp_path):
    from fmpy import read_model_description

    out = tmp_path / "sub" / "example-3.6.fmu"
    out.parent.mkdir()  # an output's folder must exist (issue 30, item 9)
    proc = cli("export-loop", "example-3.6", "--set", "u0=4", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == str(out)
    md = read_model_description(str(out), validate=True)
    assert md.coSimulation.modelIdentifier == "example_3_6"
    assert sorted(v.name for v in md.modelVariables if v.causality == "output") == ["u", "x"]
    assert float(md.defaultExperiment.stepSize) == pytest.approx(0.01)


def test_without_the_timing_fixes_the_container_is_off(tmp_path):
    """What the container does to the plain loop (measured): its default (parallel, i.e.
    Jacobi) stepping with the plain delays and a controller that samples its current input
    misses the reference by far more than round-off (0.1 to 1 in x on Example 3.6, Figure
    3). This is why export-loop changes the order, the delays and the sampling."""
    from fmpy import simulate_fmu
    from fmu_manipulation_toolbox.assembly import Assembly

    from delaycomp.fmu.cache import fmu_path

    c = check.case("example-3.6/fig3")
    spec = _spec(c)
    files = {}
    for inst in spec.instances:
        src = fmu_path(*inst.source.build_key())
        (tmp_path / src.name).write_bytes(src.read_bytes())
        files[inst.name] = src.name
    desc = container.description(spec, files, "plain.fmu")
    h = spec.T / spec.N
    desc["sequential"] = False
    desc["start"] = [[f, k, v] for f, k, v in desc["start"] if k != "held_sample"]
    for row in desc["start"]:
        if row[1] == "delay":
            row[2] = repr(float(row[2]) - h)
    (tmp_path / "plain.json").write_text(json.dumps(desc), encoding="utf-8")
    logging.getLogger("fmu_manipulation_toolbox").setLevel(logging.ERROR)
    Assembly("plain.json", fmu_directory=tmp_path).make_fmu()
    res = simulate_fmu(str(tmp_path / "plain.fmu"), stop_time=c.stop_time(),
                       output_interval=spec.T, output=["x", "u"])
    header, ref = c.reference()
    err = np.abs(np.asarray(res["x"]) - ref[::spec.N, header.index("plant.x")])
    assert err.max() > 1e-2


#: an LTI scenario, a dead-beat one (n = 3) and a model file's loop (translated to C)
FMI3_CASES = ["example-3.6/fig3", "corollary-3.7/n2", "example-3.8/delayed"]


def _fmi_versions(path) -> tuple[str, list[str]]:
    """The container's ``fmiVersion`` and those of the FMUs it holds."""
    import zipfile

    def version(text: bytes) -> str:
        found = re.search(rb'fmiVersion="([^"]+)"', text)
        assert found is not None
        return found.group(1).decode()

    with zipfile.ZipFile(path) as zf:
        inner = sorted(n for n in zf.namelist()
                       if re.fullmatch(r"resources/\d+/modelDescription\.xml", n))
        return version(zf.read("modelDescription.xml")), [version(zf.read(n)) for n in inner]


@pytest.mark.parametrize("case_id", tiered(FMI3_CASES, {"example-3.8/delayed"}))
def test_fmi3_container_is_the_fmi2_container_bit_for_bit(case_id, tmp_path):
    """``export_loop(..., fmi=3)``: an FMI 3.0 container holding the four FMI 3.0 native
    FMUs, built with the loop's values as start values (the container sets no array),
    gives the FMI 2.0 container of the FMI 2.0 native FMUs at every sampling instant bit
    for bit (the same C arithmetic in the same order, on this machine), and so meets the
    reference within check's tolerances."""
    from delaycomp.fmu.twins import native_fmus

    c = check.case(case_id)
    spec = _spec(c)
    three = container.export_loop(spec, tmp_path / "three.fmu", fmi=3)
    assert _fmi_versions(three) == ("3.0", ["3.0"] * 4)
    two = container.export_loop(spec, tmp_path / "two.fmu",
                                fmus=native_fmus(spec, tmp_path / "native"))
    assert _fmi_versions(two) == ("2.0", ["2.0"] * 4)
    names, times, data = container._simulate_in_child(three, c)
    names2, times2, data2 = container._simulate_in_child(two, c)
    assert names == names2 and np.array_equal(times, times2)
    assert np.array_equal(data, data2), np.abs(data - data2).max()
    assert len(times) == round(c.stop_time() / spec.T) + 1
    cmp = check.compare(c, names, times, data, ref_stride=spec.N)
    assert cmp.passed, (cmp.max_error, cmp.tolerance)


def test_export_loop_fmi3_cli_writes_an_fmi3_fmu_that_fmpy_validates(tmp_path):
    from fmpy import read_model_description

    out = tmp_path / "example-3.6.fmu"
    proc = cli("export-loop", "example-3.6", "--set", "u0=4", "--fmi", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == str(out)
    md = read_model_description(str(out), validate=True)
    assert md.fmiVersion == "3.0" and md.coSimulation.modelIdentifier == "example_3_6"
    assert sorted(v.name for v in md.modelVariables if v.causality == "output") == ["u", "x"]
    assert float(md.defaultExperiment.stepSize) == pytest.approx(0.01)
    assert _fmi_versions(out) == ("3.0", ["3.0"] * 4)


def test_export_loop_refuses_another_fmi_version_and_fmus_with_fmi3(tmp_path):
    from delaycomp.errors import ParameterError

    spec = _spec(check.case("example-3.6/fig3"))
    for fmi in (1, 4, True, "3"):
        with pytest.raises(ParameterError, match=re.escape(
                f"fmi = {fmi!r} is not allowed: must be 2 or 3")):
            container.export_loop(spec, tmp_path / "x.fmu", fmi=fmi)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match=re.escape(
            "fmus is not allowed with fmi = 3: the container holds delaycomp's FMI 3.0 FMUs")):
        container.export_loop(spec, tmp_path / "x.fmu", fmus={"plant": tmp_path / "p.fmu"},
                              fmi=3)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, message", [
    (["export-loop", "example-9.9", "--out", "x.fmu"], "unknown scenario 'example-9.9'"),
    (["export-loop", "example-3.6", "--fmi", "3", "--python", "--out", "x.fmu"],
     "--fmi 3 is not allowed with --python: delaycomp's FMI 3.0 FMUs are the native C ones"),
    (["export-loop", "example-3.6", "--fmi", "3", "--set", "r=0", "--out", "x.fmu"],
     "r = 0.0 is not allowed for export-loop: the measurement delay must be at least one "
     "base step"),
    (["export-loop", "example-3.6", "--out", "x.zip"], "--out 'x.zip' is not allowed: must "
                                                       "end in .fmu"),
    (["export-loop", "example-3.6", "--set", "r=0", "--out", "x.fmu"],
     "r = 0.0 is not allowed for export-loop: the measurement delay must be at least one "
     "base step"),
    (["export-loop", "example-3.6", "--set", "T=0", "--out", "x.fmu"], "T = '0' is not allowed"),
    (["crosscheck", "--out", "xc", "--case", "example-3.6/fig9"],
     "no reference case 'example-3.6/fig9'"),
])
def test_bad_input_is_one_line_exit_2(args, message, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "delaycomp.cli", *args], capture_output=True,
                          text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("delaycomp: error: ")
    assert message in proc.stderr
    assert not list(tmp_path.iterdir())


def test_check_prints_the_rows_of_both_providers():
    proc = cli("check", "--master", "fmu-alone", "--master", "container", "--case",
               "example-3.8/default")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = [line for line in proc.stdout.splitlines() if line.startswith("| example-3.8")]
    assert [r.split("|")[2].strip() for r in rows] == ["fmu-alone", "container"]
    assert all(r.split("|")[5].strip().startswith("yes") for r in rows)


@pytest.mark.parametrize("case_id", ["example-3.6/fig2", "example-3.8/delayed"])
def test_held_sample_in_our_master_with_the_measurement_delay_one_step_shorter(case_id):
    """held_sample alone, in our master: the controller samples at t_i the input held over
    [t_i - h, t_i), so with the measurement delay r - h it receives x(t_i - r) again and
    the loop reproduces the reference to round-off (1e-9 (1 + |ref|)). With the delay r it
    would sample x(t_i - r - h): off by far more."""
    c = check.case(case_id)
    spec = _spec(c)
    h = spec.T / spec.N
    for shift, should_pass in ((h, True), (0.0, False)):
        meas = spec.by_role("meas_delay")
        shifted = spec.set_parameters("controller", held_sample=True).set_parameters(
            meas.name, delay=meas.parameters["delay"] - shift)
        res = run_loop(shifted, c.stop_time())
        assert res.success, res.message
        cmp = check.compare(c, res.names, res.times, res.data)
        assert cmp.passed is should_pass, (shift, cmp.max_error)
