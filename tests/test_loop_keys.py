"""The loop-file reference page says what the reader does (issue 27, item 2).

The page's key tables are generated from ``delaycomp.system.loopkeys`` when the site is
built; the reader takes its allowed keys and defaults from the same table. These tests hold
the reader's behaviour to it, for every kind of loop: a key the table calls required, left
out, is refused in one line naming it; a default the table gives, written out, builds the
same loop as the key left out; a key the table does not list is refused.
"""

from __future__ import annotations

import copy
import re
import shutil
from pathlib import Path

import pytest

from delaycomp.errors import ParameterError
from delaycomp.system.loopfile import build
from delaycomp.system.loopkeys import DEFAULTS, KINDS, ODE_TOL, TABLE, allowed, required
from tests.cfmu.build import build_oscillator

from .conftest import REPO

OSC_PARAMETERS = {"stiffness": -1.0, "damping": 0.2, "mass": 1.0, "position_start": 1.0,
                  "velocity_start": 0.0, "substep": 0.01}


def _minimal(kind: str) -> dict:
    """A valid loop file of ``kind`` with its required keys and little else (the FMU loops
    keep ``r``, ``tau``: with both 0 the test plant's feedthrough output closes a cycle)."""
    fmu_plant = {"fmu": "Oscillator.fmu", "states": ["position", "velocity"],
                 "inputs": ["force"], "x0": [1.0, 0.0], "parameters": dict(OSC_PARAMETERS)}
    timing = {"T": 0.5, "N": 50, "r": 0.3, "tau": 0.5}
    return {
        "lti": {"T": 1.0, "plant": {"A": [[1.0]], "B": [[1.0]], "x0": [1.0]},
                "controller": {"K": [[-2.0]]}},
        "model": {"T": 1.0, "plant": {"model": "cart.py", "x0": [1.0, 0.0]},
                  "controller": {}},
        "fmu-lti": {**timing, "plant": fmu_plant,
                    "controller": {"A": [[0, 1], [1, -0.2]], "B": [[0], [1]],
                                   "K": [[-3.0, -2.5]]}},
        "fmu-model": {**timing, "plant": fmu_plant, "controller": {"model": "cart.py"}},
        "fmu-plant-fmu": {**timing, "plant": fmu_plant,
                          "controller": {"predictor": "plant-fmu", "K": [[-3.0, -2.5]]}},
    }[kind]


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("loopkeys")
    build_oscillator(folder)
    shutil.copy(REPO / "docs" / "examples" / "cart.py", folder / "cart.py")
    return folder


def _kinds_of(entry) -> list[str]:
    return [k for k in KINDS if k in entry.kinds]


@pytest.mark.parametrize("kind", KINDS)
def test_minimal_loops_build(base, kind):
    loop = build(_minimal(kind), base)
    assert loop.timing.T > 0


REQUIRED = [(kind, table, key) for kind in KINDS for table in ("", "plant", "controller")
            for key in required(table, kind)]


@pytest.mark.parametrize("kind,table,key", REQUIRED)
def test_a_required_key_left_out_is_refused_naming_it(base, kind, table, key):
    data = copy.deepcopy(_minimal(kind))
    del (data[table] if table else data)[key]
    with pytest.raises(ParameterError) as info:
        build(data, base)
    message = str(info.value)
    assert "\n" not in message
    assert re.search(rf"(?<![\w]){re.escape(key)}(?![\w])", message), message


def test_every_kind_requires_T_x0_and_its_plant():
    """The table's required keys, as the reference page shows them."""
    for kind in KINDS:
        assert required("", kind) == ("T",)
        assert "x0" in required("plant", kind)
    assert required("plant", "lti") == ("A", "B", "x0")
    assert required("plant", "model") == ("model", "x0")
    assert required("plant", "fmu-lti") == ("fmu", "states", "inputs", "x0")
    assert required("controller", "fmu-plant-fmu") == ("predictor", "K")


DEFAULTED = [(kind, name, value) for name, value in DEFAULTS.items()
             for entry in TABLE
             if (f"{entry.table}.{entry.key}" if entry.table else entry.key) == name
             for kind in _kinds_of(entry) if entry.table != "reference"]


@pytest.mark.parametrize("kind,name,value", DEFAULTED)
def test_a_default_written_out_builds_the_same_loop(base, kind, name, value):
    data = _minimal(kind)
    table, _, key = name.rpartition(".")
    spelled = copy.deepcopy(data)
    (spelled[table] if table else spelled)[key] = value
    left_out = copy.deepcopy(data)
    (left_out[table] if table else left_out).pop(key, None)
    assert build(spelled, base) == build(left_out, base)
    # the comparison can fail: another value of a timing key or the mode changes the loop
    other = {"N": 20, "r": 0.5, "controller.mode": "uncompensated"}.get(name)
    if other is not None:
        changed = copy.deepcopy(data)
        (changed[table] if table else changed)[key] = other
        assert build(changed, base) != build(left_out, base)


def test_zero_inputs_and_the_ode_tolerance_as_the_table_says(base):
    from delaycomp.maths.predictors import DEFAULT_TOL

    assert ODE_TOL == DEFAULT_TOL
    data = _minimal("lti")
    spelled = copy.deepcopy(data)
    spelled["controller"]["u0"] = [0.0]
    assert build(spelled, base) == build(data, base)


@pytest.mark.parametrize("kind", KINDS)
def test_a_key_the_table_does_not_list_is_refused(base, kind):
    for table in ("plant", "controller"):
        data = copy.deepcopy(_minimal(kind))
        data[table]["bogus_key"] = 1.0
        with pytest.raises(ParameterError) as info:
            build(data, base)
        message = str(info.value)
        assert "unknown key 'bogus_key'" in message
        for key in allowed(table, kind):
            assert key in message, (key, message)


def test_reference_table_defaults_and_requirements(tmp_path):
    from delaycomp.verify.cases import loop_case

    text = (REPO / "delaycomp" / "paper" / "loops" / "example-3.6.toml").read_text()
    (tmp_path / "ref.csv").write_text("time,plant.x\n0,1\n", encoding="utf-8")
    (tmp_path / "a.toml").write_text(text + '\n[reference]\ncsv = "ref.csv"\n')
    (tmp_path / "b.toml").write_text(text + '\n[reference]\ncsv = "ref.csv"\ntolerance = '
                                     f'{DEFAULTS["reference.tolerance"]!r}\n')
    (tmp_path / "c.toml").write_text(text + '\n[reference]\ntolerance = 1e-6\n')
    assert loop_case(tmp_path / "a.toml").tolerance == loop_case(tmp_path / "b.toml").tolerance
    with pytest.raises(ParameterError, match=r"\bcsv\b"):
        loop_case(tmp_path / "c.toml")
    assert required("reference", "lti") == ("csv",)


def test_the_reference_page_is_generated_from_the_table():
    page = (REPO / "docs" / "reference" / "loop-files.md").read_text(encoding="utf-8")
    assert "<!-- delaycomp:loop-keys -->" in page
    # no hand-written key table left beside the generated one
    assert "| key | type | required | meaning |" not in page
    from delaycomp.system.loopfile import KEYS
    from delaycomp.system.loopkeys import markdown

    text = markdown({k: s.allowed for k, s in KEYS.items()})
    for kind in ("lti", "model"):
        for key in allowed("plant", kind):
            assert f"| `{key}` |" in text
    rows = {line.split("|")[1].strip(): line.split("|")[3].strip()
            for line in text.splitlines() if line.startswith("| `")}
    assert rows["`T`"] == "required"
    assert rows["`N`"] == "`100`" and rows["`r`"] == "`0.0`" and rows["`tau`"] == "`0.0`"
