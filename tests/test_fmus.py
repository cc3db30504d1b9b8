"""The built FMUs: validity, self-containment, documentation, exact behaviour, bad input."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from delaycomp.fmu.build import FMUS, build_fmu
from delaycomp.orchestrator.fmu import FmuComponent, FmuRefused

pytestmark = pytest.mark.fmu

KINDS = sorted(kind for kind, spec in FMUS.items() if not spec.template)


def fmu_file(fmu_dir: Path, kind: str) -> Path:
    return fmu_dir / f"{FMUS[kind].model_identifier}.fmu"


@pytest.mark.parametrize("kind", KINDS)
def test_fmpy_validate_finds_no_problems(fmu_dir, kind):
    assert validate_fmu(str(fmu_file(fmu_dir, kind))) == []


@pytest.mark.parametrize("kind", KINDS)
def test_instantiates_in_a_fresh_process_elsewhere_with_bundled_code(fmu_dir, kind, tmp_path):
    """Run the FMU from another folder; the maths must come from the FMU's resources."""
    code = (
        "import sys\n"
        "from fmpy import simulate_fmu\n"
        f"simulate_fmu({str(fmu_file(fmu_dir, kind))!r}, stop_time=1.0, output_interval=0.1)\n"
        "import delaycomp\n"
        "assert '/resources/delaycomp/' in delaycomp.__file__.replace('\\\\', '/'), "
        "delaycomp.__file__\n"
        "print('ok')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("ok")


def readme_table(folder: Path, ident: str) -> list[dict]:
    """Rows of the table that follows ``<!-- table: ident -->`` in the folder's README."""
    lines = (folder / "README.md").read_text(encoding="utf-8").splitlines()
    start = lines.index(f"<!-- table: {ident} -->")
    rows = []
    for line in lines[start + 1:]:
        if not line.startswith("|"):
            if rows:
                break
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[0] not in ("name", "---"):
            rows.append(dict(zip(["name", "causality", "variability", "unit", "start",
                                  "description"], cells)))
    return rows


def assert_table_matches(rows, md):
    assert [r["name"] for r in rows] == [v.name for v in md.modelVariables]
    for row, var in zip(rows, md.modelVariables):
        assert (row["causality"], row["variability"]) == (var.causality, var.variability)
        assert row["description"] == var.description
        if var.start is not None:
            assert row["start"] == str(var.start)


@pytest.mark.parametrize("kind", KINDS)
def test_readme_table_matches_model_description(fmu_dir, kind):
    md = read_model_description(str(fmu_file(fmu_dir, kind)))
    assert_table_matches(readme_table(FMUS[kind].folder, FMUS[kind].model_identifier), md)


@pytest.mark.parametrize("kind", ["model_plant", "model_controller",
                                  "stamped_model_controller"])
def test_readme_table_of_the_model_templates(fmu_dir, kind):
    from delaycomp.fmu.cache import fmu_path
    from delaycomp.paper.models import path

    fmu = fmu_path(kind, {"model": str(path("example_3_8"))}, fmu_dir)
    md = read_model_description(str(fmu))
    ident = f"{FMUS[kind].model_identifier}_example_3_8"
    assert md.coSimulation.modelIdentifier.startswith(ident + "_")
    assert validate_fmu(str(fmu)) == []
    assert_table_matches(readme_table(FMUS[kind].folder, ident), md)


@pytest.mark.parametrize("kind", KINDS)
def test_rebuild_is_reproducible(fmu_dir, kind, tmp_path):
    """GUID and value references are pinned: a rebuild gives the same modelDescription."""
    again = build_fmu(kind, tmp_path)
    a = read_model_description(str(fmu_file(fmu_dir, kind)))
    b = read_model_description(str(again))
    assert a.guid == b.guid
    assert [(v.name, v.valueReference) for v in a.modelVariables] == \
           [(v.name, v.valueReference) for v in b.modelVariables]


def test_dependencies_declare_feedthrough(fmu_dir):
    ft = {kind: FmuComponent(kind, fmu_file(fmu_dir, kind)).feedthrough_outputs
          for kind in KINDS}
    # the channel's y is its input where a packet is seen in the step it is sent (no
    # delay); its stamp is a time, never an input
    assert ft == {"plant": frozenset(), "delay": frozenset({"y"}),
                  "channel": frozenset({"y"}), "controller": frozenset({"u"}),
                  "stamped_controller": frozenset({"u"})}


def test_bundles_its_config_and_version(fmu_dir):
    with zipfile.ZipFile(fmu_file(fmu_dir, "plant")) as z:
        config = json.loads(z.read("resources/delaycomp_fmu.json"))
        names = z.namelist()
    import delaycomp
    assert config["version"] == delaycomp.__version__
    assert "resources/delaycomp/maths/lti.py" in names


def test_delay_fmu_boundary_through_fmpy(fmu_dir):
    """u = 1 from t = 0, history 0, delay 0.3, h = 0.1: y = 0 up to 0.2, 1 from 0.3."""
    res = simulate_fmu(str(fmu_file(fmu_dir, "delay")), stop_time=1.0, output_interval=0.1,
                       start_values={"delay": 0.3, "u0[1]": 0.0},
                       input=np.array([(0.0, 1.0)], dtype=[("time", float), ("u", float)]))
    t, y = res["time"], res["y"]
    assert y[np.isclose(t, 0.2)][0] == 0.0
    assert y[np.isclose(t, 0.3)][0] == 1.0
    assert np.all(y[t < 0.25] == 0.0) and np.all(y[t > 0.25] == 1.0)


def test_plant_fmu_is_the_exact_exponential(fmu_dir):
    res = simulate_fmu(str(fmu_file(fmu_dir, "plant")), stop_time=2.0, output_interval=0.01,
                       start_values={"A[1,1]": -0.7, "B[1,1]": 2.0, "x0[1]": 1.5},
                       input=np.array([(0.0, 0.4)], dtype=[("time", float), ("u", float)]))
    t = res["time"]
    exact = np.exp(-0.7 * t) * 1.5 + (1 - np.exp(-0.7 * t)) * 2.0 * 0.4 / 0.7
    np.testing.assert_allclose(res["x"], exact, rtol=1e-12, atol=1e-14)


BAD = [
    ("controller", {"T": -1.0}, r"T = -1.0 is not allowed: must be > 0"),
    ("controller", {"r": -0.1}, r"r = -0.1 is not allowed: must be >= 0"),
    ("controller", {"tau": 0.5},
     r"tau = 0.5 is not allowed: zero-order hold needs a multiple l\*T"),
    ("controller", {"mode": "fast"}, r"mode = 'fast' is not allowed"),
    ("controller", {"K[1,1]": float("nan")}, r"K\[1,1\] = nan is not allowed"),
    ("delay", {"delay": -1.0}, r"delay = -1.0 is not allowed: must be >= 0"),
    ("plant", {"A[1,1]": float("inf")}, r"A\[1,1\] = inf is not allowed"),
]


@pytest.mark.parametrize("kind,params,message", BAD,
                         ids=[f"{k}-{next(iter(p))}" for k, p, _ in BAD])
def test_bad_parameter_is_logged_and_the_fmu_refuses_to_step(fmu_dir, kind, params, message):
    """Logged as an error when initialization ends; every doStep then returns fmi2Discard.

    (pythonfmu 0.7 cannot return fmi2Error: see delaycomp/fmu/slave.py.)
    """
    comp = FmuComponent(kind, fmu_file(fmu_dir, kind))
    try:
        comp.setup(0.0, 1.0, params)
        with pytest.raises(FmuRefused, match=message):
            comp.initialize()
        assert any(m.startswith("[error]") and re.search(message, m) for m in comp.messages)
        with pytest.raises(FMICallException) as info:
            comp.do_step(0.0, 0.1)
        assert info.value.status == 2  # fmi2Discard
        assert comp.worst_status < 4  # never fatal
    finally:
        comp.terminate()  # the host survives and frees the instance


def test_delay_off_grid_fails_the_step(fmu_dir):
    comp = FmuComponent("d", fmu_file(fmu_dir, "delay"))
    try:
        comp.setup(0.0, 1.0, {"delay": 0.25})
        comp.initialize()
        with pytest.raises(FMICallException, match="fmi2DoStep"):
            comp.do_step(0.0, 0.1)
        assert "must be a multiple of the communication step" in comp.last_message
    finally:
        comp.terminate()


def test_controller_refuses_a_step_over_a_sampling_instant(fmu_dir):
    comp = FmuComponent("c", fmu_file(fmu_dir, "controller"))
    try:
        comp.setup(0.0, 3.0, {"T": 1.0, "K[1,1]": -1.0})
        comp.initialize()
        comp.do_step(0.0, 0.5)
        with pytest.raises(FMICallException, match="fmi2DoStep"):
            comp.do_step(0.5, 1.0)
        assert "passes over the sampling instant" in comp.last_message
    finally:
        comp.terminate()


def test_log_messages_reach_the_instance_that_logged_them(fmu_dir):
    """fmpy's logger proxy is process-wide; messages are routed by componentEnvironment."""
    comps = [FmuComponent(f"d{i}", fmu_file(fmu_dir, "delay")) for i in range(3)]
    try:
        for i, comp in enumerate(comps):
            comp.setup(0.0, 1.0, {"delay": -float(i + 1)})
        for i, comp in enumerate(comps):
            with pytest.raises(FmuRefused):
                comp.initialize()
            assert comp.last_message.startswith(f"delay = -{i + 1}.0 is not allowed")
    finally:
        for comp in comps:
            comp.terminate()
