"""Each FMU alone in the FMI cross-check layout (``delaycomp crosscheck``, issue 4 item 4)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from delaycomp.verify import check, crosscheck
from delaycomp.verify.crosscheck import Trace

from .conftest import REPO
from .roundoff import SAME_ARITHMETIC_ULPS, assert_columns_close

#: one reference case per scenario (all cases run in ``delaycomp check``)
ONE_PER_SCENARIO = ["example-3.6/fig3", "example-2.4/default", "example-3.8/delayed",
                    "corollary-3.7/n2", "corollary-4.1/default", "proposition-4.2/default"]
#: the committed tree: the default-dimension FMUs (Example 3.6), without the .fmu files
COMMITTED = [c for c in check.CASES if c.scenario == "example-3.6"]
TREE = REPO / "crosscheck"


def _trace(inputs, outputs):
    times = [0.1 * k for k in range(len(outputs))]
    return Trace("x", "delay", {}, {}, ["u"], ["y"], times, [[v] for v in inputs],
                 [[v] for v in outputs])


def test_input_csv_is_piecewise_constant_under_linear_interpolation():
    """A held input that changes at t_k is two rows at t_k: linear interpolation of the
    file (the rules) then gives the held value everywhere, and fmpy's Input takes the
    value after the change at t_k."""
    text = crosscheck.input_csv(_trace([1.0, 1.0, 2.0, 2.0], [0, 0, 0, 0, 0]))
    assert text.splitlines() == ['"time","u"', "0.0,1.0", "0.2,1.0", "0.2,2.0", "0.4,2.0"]


def test_ref_csv_and_opt_follow_the_rules():
    trace = _trace([1.0, 2.0], [0.5, 0.25, 0.125])
    assert crosscheck.ref_csv(trace).splitlines() == [
        '"time","y"', "0.0,0.5", "0.1,0.25", "0.2,0.125"]
    assert crosscheck.ref_opt(trace) == ("StartTime, 0.0\nStopTime, 0.2\nStepSize, 0.1\n"
                                         "RelTol, 1e-09\n")


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    """The cross-check tree of one case per scenario, with the FMUs."""
    out = tmp_path_factory.mktemp("crosscheck")
    crosscheck.generate(out, [check.case(c) for c in ONE_PER_SCENARIO])
    return out


@pytest.mark.fmu
def test_fmpy_validate_vendor_repo_accepts_the_tree(tree):
    proc = subprocess.run([sys.executable, "-m", "fmpy.cross_check.validate_vendor_repo",
                           str(tree)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"Validated {4 * len(ONE_PER_SCENARIO)} FMUs" in proc.stdout


@pytest.mark.fmu
@pytest.mark.parametrize("case_id", ONE_PER_SCENARIO)
def test_each_fmu_alone_reproduces_its_ref_csv(tree, case_id):
    """fmpy.simulate_fmu with the _in.csv and nothing else (the parameters are the FMU's
    start values) reproduces the _ref.csv. Tolerance 1e-9 (1 + |ref|): the FMU gets the
    inputs it got in the loop, only fmpy's communication points differ by round-off, and
    every component of these cases is an exact flow or a closed form (measured <= 1.4e-11,
    where |x| reaches 7)."""
    c = check.case(case_id)
    models = sorted(crosscheck.models_dir(tree).glob(f"{c.scenario}_{c.case}_*"))
    assert [m.name.rsplit("_", 1)[-1] for m in models] == ["controller", "delay", "delay",
                                                           "plant"]
    results = crosscheck.run_alone_batch(models)
    failed = [r for r in results if not r.passed]
    assert not failed, failed
    assert max(r.max_error for r in results) <= 1e-9 * 100


@pytest.mark.fmu
def test_a_wrong_parameter_is_caught(tree, tmp_path):
    """The check is not vacuous: the same files with the delay FMU's default start values
    (delay 0 instead of r) fail."""
    c = check.case("example-3.6/fig3")
    name = crosscheck.model_name(c, "meas_delay")
    src = crosscheck.models_dir(tree) / name
    bad = tmp_path / name
    bad.mkdir()
    for f in src.iterdir():
        if f.suffix != ".fmu":
            (bad / f.name).write_bytes(f.read_bytes())
    crosscheck.variant_fmu(src / f"{name}.fmu", {"delay": 0.0}, bad / f"{name}.fmu")
    result = crosscheck.run_alone_batch([bad])[0]
    assert not result.passed and result.max_error > 1e-3


@pytest.mark.fmu
def test_the_tap_does_not_change_the_loop():
    """The taps read every output right after each step; the plant's outputs (no direct
    feedthrough) must equal a run without taps (the same arithmetic: to the last bits)."""
    from delaycomp.orchestrator.simulate import run_loop
    from delaycomp.paper import scenarios

    c = check.case("example-3.6/fig3")
    traces = crosscheck.record_case(c)
    sc = scenarios.get(c.scenario)
    res = run_loop(sc.make(sc.resolve(list(c.sets))), crosscheck.stop_time(c))
    assert_columns_close(np.array(traces["plant"].outputs)[:, 0], res.column("plant.x"),
                         SAME_ARITHMETIC_ULPS, "tapped")


def _md_without_date(data: bytes) -> str:
    return re.sub(r'generationDateAndTime="[^"]*"', "", data.decode("utf-8"))


@pytest.mark.fmu
@pytest.mark.parametrize("case_id, instance", [("corollary-3.7/n2", "controller"),
                                               ("example-3.8/sin", "controller")])
def test_repackaged_fmu_equals_a_pythonfmu_build_with_those_start_values(case_id, instance,
                                                                         tmp_path):
    """The per-case FMU is the cached FMU with another modelDescription and configuration;
    pythonfmu must build the same from that configuration (matrices, strings, Integer N,
    Boolean pad, GUID)."""
    from delaycomp.fmu.build import build_fmu
    from delaycomp.fmu.cache import fmu_path

    c = check.case(case_id)
    inst = c.loop().instance(instance)
    kind, config = inst.source.build_key()
    params = dict(inst.parameters)
    variant = crosscheck.variant_fmu(fmu_path(kind, config), params, tmp_path / "v.fmu")
    built = build_fmu(kind, tmp_path / "built", {**config, "start": params}, "b.fmu")
    with zipfile.ZipFile(variant) as zv, zipfile.ZipFile(built) as zb:
        assert _md_without_date(zv.read("modelDescription.xml")) == \
            _md_without_date(zb.read("modelDescription.xml"))
        cfg = json.loads(zv.read("resources/delaycomp_fmu.json"))
        assert cfg == json.loads(zb.read("resources/delaycomp_fmu.json"))
        assert cfg["start"] == params


@pytest.mark.fmu
@pytest.mark.parametrize("c", COMMITTED, ids=[c.id for c in COMMITTED])
def test_committed_tree_is_reproduced(c, tmp_path):
    """``crosscheck/`` holds the files of the Example 3.6 cases (no .fmu: ``delaycomp
    crosscheck --out DIR`` writes them). The generator must give the same files:
    text identical but for the numbers, which may differ by round-off across machines
    (1e-12 (1 + |value|))."""
    crosscheck.generate(tmp_path, [c], with_fmus=False)
    made = crosscheck.models_dir(tmp_path)
    kept = crosscheck.models_dir(TREE)
    names = sorted(p.relative_to(made).as_posix() for p in made.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(kept).as_posix()
                           for p in kept.glob(f"{c.scenario}_{c.case}_*/*") if p.is_file())
    for rel in names:
        new, old = (made / rel).read_text(), (kept / rel).read_text()
        if not rel.endswith(".csv"):
            assert new == old, rel
            continue
        a, b = crosscheck.read_table(made / rel), crosscheck.read_table(kept / rel)
        assert a[0] == b[0] and a[1].shape == b[1].shape, rel
        assert np.all(np.abs(a[1] - b[1]) <= 1e-12 * (1 + np.abs(b[1]))), rel


def test_committed_tree_stays_small():
    size = sum(p.stat().st_size for p in TREE.rglob("*") if p.is_file())
    assert 0 < size < 600_000
    assert not list(TREE.rglob("*.fmu"))
