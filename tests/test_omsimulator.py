"""OMSimulator (OpenModelica's co-simulation engine): archives it reads as written, its
Python API as a master (``--master omsimulator``, the ``omsimulator`` rows of ``check``) and
its command line on every shipped archive.

The first group needs no OMSimulator: it checks what the SSP writer puts into every archive
(identifier names, OMSimulator's master annotation, no component annotations, no String
parameters) and the FMUs' Integer twins of their String choices. The rest needs OMSimulator:
it is found from ``DELAYCOMP_OMSIMULATOR`` (an install folder; CI sets it, and a folder
without OMSimulator fails there) or as the ``OMSimulator`` package; without either those
tests are reported as skipped with the install hint (``-ra`` lists them), never passed.

Tolerances:

- Python API against our master: ``1e-12 (1 + |ours|)``. Both masters call the same FMUs
  with the same values; OMSimulator keeps its time as ``t += h`` (3.3e-13 s off the grid at
  t = 20 s, measured), which the plant sees in its step sizes: measured 2.7e-13 on
  Example 3.6 (|u| up to 2.7);
- command line against our master: its CSV keeps 12 significant digits, so a value is
  rounded by up to ``5e-12 |v|``; ``1e-11 |ours| + 1e-12`` allows twice that plus the
  round-off above (measured at most 5e-12 over all shipped archives).
"""

from __future__ import annotations

import re
import subprocess
import zipfile

import numpy as np
import pytest
from lxml import etree

from delaycomp.cli import main
from delaycomp.formats import ssp
from delaycomp.orchestrator.inprocess import SlaveComponent, SlaveRefused
from delaycomp.orchestrator.simulate import run_loop
from delaycomp.paper import scenarios
from delaycomp.system.jacobi import CompensationError, jacobi_variant
from delaycomp.verify import omsimulator
from tests.conftest import REPO

from .roundoff import EPS, SAME_ARITHMETIC_ULPS, assert_columns_close

IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


# -- the archives, without OMSimulator ------------------------------------------------------

def _systems():
    """Every scenario at its defaults, plain and Jacobi: what `delaycomp build` ships."""
    out = []
    for name in scenarios.SCENARIOS:
        spec, info = ssp.scenario_system(name)
        out.append(pytest.param(spec, info, id=name))
        try:
            out.append(pytest.param(jacobi_variant(spec), ssp.jacobi_info(info),
                                    id=f"{name}-jacobi"))
        except CompensationError:  # pragma: no cover - every shipped scenario has one
            pass
    return out


@pytest.mark.parametrize(("spec", "info"), _systems())
def test_written_system_is_what_every_importer_reads(tmp_path, spec, info):
    ssd_path = ssp.write_system(spec, info, tmp_path)
    files = [ssd_path, *sorted((tmp_path / ssp.RESOURCES).glob("*.ssv"))]
    for f in files:
        assert ssp.validate(f) == [], f.name
    root = etree.parse(str(ssd_path)).getroot()
    system = root.find("ssd:System", ssp.NSMAP)
    assert IDENT.match(root.get("name")) and IDENT.match(system.get("name"))
    assert root.get("name") == ssp.ssd_identifier(info.name)
    for comp in system.iterfind("ssd:Elements/ssd:Component", ssp.NSMAP):
        assert IDENT.match(comp.get("name"))
        assert comp.find("ssd:Annotations", ssp.NSMAP) is None, comp.get("name")
        kinds = {etree.QName(c[0]).localname
                 for c in comp.iterfind("ssd:Connectors/ssd:Connector", ssp.NSMAP)}
        assert "String" not in kinds, comp.get("name")
    h = spec.T / spec.N
    oms = system.find(f"ssd:Annotations/ssc:Annotation[@type='{ssp.OMS_ANNOTATION}']/"
                      "oms:Annotations/oms:SimulationInformation/oms:FixedStepMaster",
                      ssp.NSMAP)
    assert oms is not None and float(oms.get("stepSize")) == h
    osp = root.find(f"ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation"
                    f"[@type='{ssp.OSP_ANNOTATION}']/osp:Algorithm/osp:FixedStepAlgorithm",
                    ssp.NSMAP)
    assert osp is not None and float(osp.get("baseStepSize")) == h
    for f in files[1:]:
        values = etree.parse(str(f)).getroot().iterfind(
            "ssv:Parameters/ssv:Parameter/*", ssp.NSMAP)
        assert {etree.QName(v).localname for v in values} <= {"Real", "Integer", "Boolean"}
    back = ssp.read_system(ssd_path)
    assert back.spec.instances == spec.instances  # the Strings come back from their twins
    assert back.spec.connections == spec.connections
    assert (back.spec.T, back.spec.N, back.spec.recorded) == (spec.T, spec.N, spec.recorded)
    assert back.info.name == info.name  # the scenario's name, not the identifier


def test_shipped_ssp_folder_has_no_string_parameter():
    folder = REPO / "ssp"
    ssvs = sorted(folder.rglob("*.ssv"))
    assert len(ssvs) == 4 * len(scenarios.SCENARIOS)
    for f in ssvs:
        assert "ssv:String" not in f.read_text(encoding="utf-8"), f


@pytest.mark.parametrize(("name", "ident"), [("example-3.6", "example_3_6"),
                                             ("corollary-4.1", "corollary_4_1"),
                                             ("2 loops", "_2_loops"), ("a_b9", "a_b9")])
def test_ssd_identifier(name, ident):
    assert ssp.ssd_identifier(name) == ident and IDENT.match(ident)


def test_string_choices_become_their_integer_twins_and_come_back():
    choices = {"mode": ("compensated", "uncompensated")}
    params = {"T": 1.0, "mode": "uncompensated", "free": "text"}
    foreign = ssp.foreign_parameters(params, choices)
    assert foreign == {"T": 1.0, "mode_index": 2, "free": "text"}
    assert ssp.native_parameters(foreign, choices, "here") == params
    # index 0 leaves the String to the FMU's default
    assert ssp.native_parameters({"mode_index": 0}, choices, "here") == {}
    with pytest.raises(ssp.SspError, match=r"mode_index = 3 is not allowed: must be 0 \.\. 2"):
        ssp.native_parameters({"mode_index": 3}, choices, "here")


def test_archive_of_the_earlier_layout_still_reads(tmp_path):
    """Archives written before kept ``dc:Fmu`` in each component and no dc:Component."""
    spec, info = ssp.scenario_system("example-3.8")
    ssd_path = ssp.write_system(spec, info, tmp_path)
    tree = etree.parse(str(ssd_path))
    root = tree.getroot()
    master = root.find("ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation/dc:Master",
                       ssp.NSMAP)
    for desc in master.findall("dc:Component", ssp.NSMAP):
        comp = root.find(f"ssd:System/ssd:Elements/ssd:Component[@name="
                         f"'{desc.get('element')}']", ssp.NSMAP)
        ann = etree.SubElement(etree.SubElement(comp, ssp.tag("ssd:Annotations")),
                               ssp.tag("ssc:Annotation"), type=ssp.DC_ANNOTATION)
        etree.SubElement(ann, ssp.tag("dc:Fmu"), role=desc.get("role"),
                         kind=desc.get("kind"), config=desc.get("config"))
        master.remove(desc)
    tree.write(str(ssd_path))
    back = ssp.read_system(ssd_path)
    assert [(i.name, i.role, i.source) for i in back.spec.instances] == \
           [(i.name, i.role, i.source) for i in spec.instances]


# -- the Integer twins in the FMU slaves --------------------------------------------------------

def _lti_controller_u(params: dict) -> float:
    """u_0 of the LTI controller of Example 3.6 (A = B = 1, K = -2, T = 1, r = 0.3) for
    y(0) = 1, with ``params`` set before initialization."""
    c = SlaveComponent("controller", "controller", {"n": 1, "m": 1})
    c.setup(0.0, 10.0, {"T": 1.0, "r": 0.3, "A[1,1]": 1.0, "B[1,1]": 1.0, "K[1,1]": -2.0,
                        **params})
    c.writer(["y"])([1.0])
    c.initialize()
    return c.reader(["u"])()[0]


COMPENSATED = -2.0 * np.exp(0.3)  # u_0 = K e^{A r} y_0 with u0 = 0 (Corollary 3.4)
UNCOMPENSATED = -2.0  # u_0 = K y_0


@pytest.mark.parametrize(("params", "u"), [
    ({}, COMPENSATED),
    ({"mode_index": 0, "mode": "uncompensated"}, UNCOMPENSATED),
    ({"mode_index": 2}, UNCOMPENSATED),
    ({"mode_index": 1}, COMPENSATED),
    ({"mode_index": 2, "mode": "uncompensated"}, UNCOMPENSATED),  # both say the same
    ({"mode_index": 2, "mode": "compensated"}, UNCOMPENSATED),  # the String at its start
], ids=["default", "string", "index-2", "index-1", "agree", "string-at-start"])
def test_mode_index_selects_the_mode(params, u):
    # the controller's e^{A r} is scipy's expm (a Pade approximant), the constant libm's exp:
    # each within a few ulp, so 16 EPS apart at most
    assert _lti_controller_u(params) == pytest.approx(u, rel=16 * EPS)


@pytest.mark.parametrize(("params", "message"), [
    ({"mode_index": 3}, r"mode_index = 3 is not allowed: must be 0 \(as mode says\) or 1 \.\. 2"),
    ({"mode_index": -1}, r"mode_index = -1 is not allowed"),
    ({"mode_index": 1, "mode": "uncompensated"},
     r"mode = 'uncompensated' and mode_index = 1 \('compensated'\) disagree"),
])
def test_bad_or_contradicting_mode_index_is_refused(params, message):
    with pytest.raises(SlaveRefused, match=message):
        _lti_controller_u(params)


# -- OMSimulator ------------------------------------------------------------------------------



@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    """Every archive `delaycomp build` ships (plain and Jacobi), with its FMUs."""
    from delaycomp.formats.ssp import pack_scenarios

    return {p.stem: p for p in pack_scenarios(tmp_path_factory.mktemp("ssp"))}


def _ours(path):
    with ssp.Archive(path) as archive:
        system = archive.system
        res = run_loop(system.spec, system.info.stop_time, fmus=archive.fmus())
        ident = ssp.ssd_identifier(system.info.name)
    assert res.success, res.message
    return system, ident, res


@pytest.mark.fmu
@pytest.mark.parametrize("name", ["example-3.6", "example-3.6-jacobi", "example-3.8"])
def test_python_api_reproduces_our_master(oms, shipped, name):
    system, _, ours = _ours(shipped[name])
    res = omsimulator.run_ssp(shipped[name], system.info.stop_time)
    assert res.success, res.message
    assert res.names == ours.names
    assert_columns_close(res.times, ours.times, SAME_ARITHMETIC_ULPS, "time")
    assert np.all(np.abs(res.data - ours.data) <= 1e-12 * (1 + np.abs(ours.data)))


@pytest.mark.fmu
def test_a_run_that_stops_early_is_an_error_with_omsimulators_message(oms, shipped,
                                                                       tmp_path):
    """A controller with T = -1 refuses to initialize; OMSimulator stops at once."""
    bad = tmp_path / "bad.ssp"
    with zipfile.ZipFile(shipped["example-3.6"]) as src, \
            zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "resources/controller.ssv":
                data = data.replace(b'<ssv:Parameter name="T">\n      <ssv:Real value="1.0"/>',
                                    b'<ssv:Parameter name="T">\n      <ssv:Real value="-1.0"/>')
                assert b'value="-1.0"' in data
            dst.writestr(item, data)
    res = omsimulator.run_ssp(bad, 20.0)
    assert not res.success
    assert "before t = " in res.message and "T = -1.0 is not allowed" in res.message
    rc = main(["run", str(bad), "--master", "omsimulator", "--out", str(tmp_path / "x.csv")])
    assert rc == 1 and not (tmp_path / "x.csv").exists()


@pytest.mark.fmu
def test_cli_master_writes_our_csv(oms, shipped, tmp_path):
    out = tmp_path / "oms.csv"
    assert main(["run", str(shipped["example-3.6"]), "--master", "omsimulator",
                 "--out", str(out)]) == 0
    assert main(["run", str(shipped["example-3.6"]), "--out", str(tmp_path / "ours.csv")]) == 0
    a = np.loadtxt(out, delimiter=",", skiprows=1)
    b = np.loadtxt(tmp_path / "ours.csv", delimiter=",", skiprows=1)
    assert a.shape == b.shape
    assert np.all(np.abs(a - b) <= 1e-12 * (1 + np.abs(b)))


@pytest.mark.fmu
@pytest.mark.parametrize("name", [f"{s}{v}" for s in scenarios.SCENARIOS
                                  for v in ("", "-jacobi")])
def test_command_line_runs_every_shipped_archive(oms, shipped, tmp_path, name):
    """`OMSimulator --stopTime=S --resultFile=F file.ssp`, with the environment pythonfmu
    FMUs need there, to the stop time, with our master's trajectory and no error logged.

    Its exit status is not the verdict: it exits 0 when an FMU stops the run early (see
    the issue), and pythonfmu's interpreter teardown at exit has crashed it after the
    result was written (SIGSEGV/SIGABRT, measured in 1 run of 12; DESIGN.md, non-Python
    hosts): the result file and the log are checked instead."""
    system, ident, ours = _ours(shipped[name])
    result = tmp_path / "result.csv"
    argv, env = omsimulator.cli_command(shipped[name], system.info.stop_time, result)
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)
    log = proc.stdout + proc.stderr
    assert proc.returncode in (0, -6, -11), log[-2000:]
    assert not [ln for ln in log.splitlines() if ln.startswith("error:")], log[-2000:]
    times, data = omsimulator.read_cli_result(result, ident, system.spec.recorded)
    assert times[-1] == system.info.stop_time
    np.testing.assert_allclose(times, ours.times, rtol=0, atol=1e-9)
    assert np.all(np.abs(data - ours.data) <= 1e-11 * np.abs(ours.data) + 1e-12)


def test_not_installed_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv(omsimulator.ENV, str(tmp_path))
    with pytest.raises(omsimulator.NotInstalled, match="holds no lib/x86_64-linux-gnu/"):
        omsimulator.locate()
    from delaycomp.verify import check
    row = check.run_checks(check.CASES[:1], ["omsimulator"])[0]
    assert row.passed is False and "not installed" in row.note


def test_cli_env_has_the_three_settings():
    env = omsimulator.cli_env({})
    assert env["LD_PRELOAD"].endswith(".so") or ".so." in env["LD_PRELOAD"]
    assert env["PYTHONHOME"] and env["PYTHONPATH"]
    import numpy

    assert any(numpy.__file__.startswith(p) for p in env["PYTHONPATH"].split(":"))
