"""SSP: every scenario's SSD/SSV is valid SSP 1.0, reads back into the loop the master runs,
the committed ``ssp/`` folder is what the code generates, and ``run FILE.ssp`` gives the
same trajectory as ``run NAME``."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from lxml import etree

from delaycomp.formats import ssp
from delaycomp.paper.scenarios import SCENARIOS

from .conftest import REPO
from .roundoff import (
    COMMITTED_ULPS,
    SAME_ARITHMETIC_ULPS,
    assert_csv_close,
    assert_same_values,
    assert_text_close,
    read_table,
)
from .test_cli import cli

NAMES = list(SCENARIOS)


def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def test_committed_ssp_folder_equals_a_fresh_generation(tmp_path):
    """``ssp/`` is generated (``delaycomp ssp --out ssp``): it must not drift from the code.
    The XML is compared exactly but for its numbers, which are compared to round-off
    (``COMMITTED_ULPS``)."""
    ssp.write_all(tmp_path)
    committed = REPO / "ssp"
    assert _files(committed) == _files(tmp_path)
    for f in _files(tmp_path):
        assert_text_close((tmp_path / f).read_text(encoding="utf-8"),
                          (committed / f).read_text(encoding="utf-8"), COMMITTED_ULPS,
                          what=f"{f} (regenerate with `delaycomp ssp --out ssp`)")


@pytest.mark.parametrize("name", NAMES)
def test_committed_ssd_and_ssv_are_valid_ssp_1_0(name):
    folder = REPO / "ssp" / name
    files = [folder / ssp.SSD_NAME, *sorted((folder / ssp.RESOURCES).glob("*.ssv"))]
    assert len(files) == 5  # the SSD and one parameter set per component
    for f in files:
        assert ssp.validate(f) == []


@pytest.mark.parametrize("name", NAMES)
def test_committed_ssd_reads_back_into_the_scenario_loop(name):
    spec, info = ssp.scenario_system(name)
    system = ssp.read_system(REPO / "ssp" / name / ssp.SSD_NAME)
    # the committed numbers against the code's, to round-off (COMMITTED_ULPS); the rest,
    # types included, exactly
    assert_same_values(system.spec, spec, COMMITTED_ULPS, "spec")
    assert system.info == info
    assert set(system.sources) == set(spec.names)


ROUND_TRIPS = [
    ("example-3.6", ["r=0.1", "mode=uncompensated", "k=2.5", "r_true=0.2", "N=50"]),
    ("corollary-3.7", ["n=5", "r=2.2", "tau=0"]),
    ("example-2.4", ["law=printed", "predictor=numerical", "T=2"]),
    ("proposition-4.2", ["u0=0.3,-0.2", "tau=0.75", "pad=1"]),
]


@pytest.mark.parametrize("name,sets", ROUND_TRIPS, ids=[n for n, _ in ROUND_TRIPS])
def test_write_then_read_round_trip(tmp_path, name, sets):
    spec, info = ssp.scenario_system(name, sets, parameter_set="case")
    ssp.write_system(spec, info, tmp_path)
    back = ssp.read_system(tmp_path / ssp.SSD_NAME)
    assert back.spec == spec  # values, their types (bool, int, float, str) and order
    assert back.info == info
    for f in tmp_path.rglob("*.s?d"):
        assert ssp.validate(f) == []


def test_master_settings_are_annotated_for_us_and_for_libcosim():
    root = etree.parse(str(REPO / "ssp" / "example-3.6" / ssp.SSD_NAME)).getroot()
    assert root.nsmap["osp"] == ssp.OSP_NS  # libcosim reads osp: only when declared here
    alg = root.find("ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation"
                    "[@type='com.opensimulationplatform']/osp:Algorithm/"
                    "osp:FixedStepAlgorithm", ssp.NSMAP)
    assert float(alg.get("baseStepSize")) == 0.01
    master = root.find(f"ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation"
                       f"[@type='{ssp.DC_ANNOTATION}']/dc:Master", ssp.NSMAP)
    assert (master.get("T"), master.get("N"), master.get("h")) == ("1.0", "100", "0.01")


def test_validation_rejects_an_invalid_ssd(tmp_path):
    """The validator is not vacuous: an SSD without its required version is refused."""
    text = (REPO / "ssp" / "example-3.6" / ssp.SSD_NAME).read_text(encoding="utf-8")
    bad = tmp_path / ssp.SSD_NAME
    bad.write_text(text.replace(' version="1.0"', "", 1), encoding="utf-8")
    errors = ssp.validate(bad)
    assert errors and "version" in errors[0]


# -- running an SSP in our master ---------------------------------------------------------

RUNS = [
    ("example-3.6", ["r=0.3", "u0=4"], "20"),
    ("example-3.8", ["tau=1", "r=1.5"], "8"),
    ("corollary-4.1", [], "5"),
]


@pytest.mark.fmu
@pytest.mark.parametrize("name,sets,stop", RUNS, ids=[n for n, _, _ in RUNS])
def test_run_ssp_gives_the_same_trajectory_as_run_name(tmp_path, name, sets, stop):
    """Same FMUs, same master, same parameters: the CSVs are the same (to the last bits,
    ``SAME_ARITHMETIC_ULPS``: two processes)."""
    packed = tmp_path / f"{name}.ssp"
    sset = [a for s in sets for a in ("--set", s)]
    assert cli("ssp", name, *sset, "--out", str(packed)).returncode == 0
    a = cli("run", str(packed), "--stop-time", stop, "--out", str(tmp_path / "a.csv"))
    b = cli("run", name, *sset, "--stop-time", stop, "--out", str(tmp_path / "b.csv"))
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    assert_csv_close(tmp_path / "a.csv", tmp_path / "b.csv", SAME_ARITHMETIC_ULPS)


@pytest.mark.fmu
def test_run_ssp_set_changes_an_fmu_parameter(tmp_path):
    packed = tmp_path / "fig.ssp"
    assert cli("ssp", "example-3.6", "--set", "r=0.3", "--out", str(packed)).returncode == 0
    a = cli("run", str(packed), "--set", "controller.mode=uncompensated", "--stop-time", "5",
            "--out", str(tmp_path / "a.csv"))
    b = cli("run", "example-3.6", "--set", "r=0.3", "--set", "mode=uncompensated",
            "--stop-time", "5", "--out", str(tmp_path / "b.csv"))
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    assert_csv_close(tmp_path / "a.csv", tmp_path / "b.csv", SAME_ARITHMETIC_ULPS)
    c = cli("run", str(packed), "--stop-time", "5", "--out", str(tmp_path / "c.csv"))
    assert c.returncode == 0, c.stderr
    # without the --set the loop is the compensated one: far apart, not by round-off
    diff = np.abs(read_table(tmp_path / "c.csv")[1] - read_table(tmp_path / "a.csv")[1])
    assert diff.max() > 1e-3


def _corrupt(kind, tmp_path, good):
    path = tmp_path / f"{kind}.ssp"
    if kind == "not-a-zip":
        path.write_text("not a zip", encoding="utf-8")
    elif kind == "no-ssd":
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("readme.txt", "hello")
    elif kind == "foreign":  # a valid SSD from another tool: no delaycomp annotation
        text = (REPO / "ssp" / "example-3.6" / ssp.SSD_NAME).read_text(encoding="utf-8")
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr(ssp.SSD_NAME, text.replace(ssp.DC_ANNOTATION, "com.example"))
    elif kind == "missing-fmu":
        with zipfile.ZipFile(good) as src, zipfile.ZipFile(path, "w") as zf:
            for item in src.namelist():
                if not item.endswith("DelaycompPlantLTI.fmu"):
                    zf.writestr(item, src.read(item))
    elif kind == "bad-xml":
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr(ssp.SSD_NAME, "<ssd:System")
    return path


CORRUPT = [("not-a-zip", "not an SSP archive"), ("no-ssd", "no SystemStructure.ssd"),
           ("foreign", "not a delaycomp system"), ("missing-fmu", "is missing"),
           ("bad-xml", "not readable XML")]


@pytest.mark.fmu
@pytest.mark.parametrize("kind,message", CORRUPT, ids=[k for k, _ in CORRUPT])
def test_corrupt_or_foreign_ssp_is_one_line_exit_2(tmp_path, kind, message):
    good = tmp_path / "good.ssp"
    if kind == "missing-fmu":
        assert cli("ssp", "example-3.6", "--out", str(good)).returncode == 0
    proc = cli("run", str(_corrupt(kind, tmp_path, good)))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("delaycomp: error: "), proc.stderr
    assert message in lines[0]


@pytest.mark.fmu
def test_bad_set_on_an_ssp_is_one_line_exit_2(tmp_path):
    packed = tmp_path / "x.ssp"
    assert cli("ssp", "example-3.6", "--out", str(packed)).returncode == 0
    for assignment, message in (("mode=fast", "instance.parameter=VALUE"),
                                ("ctl.k=1", "no instance 'ctl'"),
                                ("controller.k=1", "has no parameter 'k'"),
                                ("plant.x0[1]=abc", "must be a finite Real")):
        proc = cli("run", str(packed), "--set", assignment)
        assert proc.returncode == 2 and message in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
