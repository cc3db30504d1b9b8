"""``--set`` values are ASCII decimal literals only (issue 16, item 8).

Python's ``float`` and ``int`` accept other scripts' digits and underscores: before the
fix ``k=١`` (Arabic-Indic one) meant 1, ``k=２`` (fullwidth two) meant 2, ``k=1_000``
meant 1000 and ``N=١٠`` meant 10. Each is now refused with the usual one-line message.
"""

from __future__ import annotations

import pytest

from delaycomp.paper import scenarios
from delaycomp.paper.scenarios import ParameterError


@pytest.mark.parametrize("text", ["١", "２", "1_000", "1.5_0", "𝟏", "1e1_0", "0x10", ""])
def test_non_ascii_or_underscored_reals_are_refused(text):
    sc = scenarios.get("example-3.6")
    with pytest.raises(ParameterError, match=r"^parameter k = .* is not allowed: must be "):
        sc.resolve([f"k={text}"])


@pytest.mark.parametrize("text", ["١٠", "1_0", "+１0", "2.5"])
def test_non_ascii_or_underscored_integers_are_refused(text):
    sc = scenarios.get("example-3.6")
    with pytest.raises(ParameterError, match=r"^parameter N = .* is not allowed: must be "):
        sc.resolve([f"N={text}"])


@pytest.mark.parametrize("text,value", [("50", 50), ("1e2", 100), ("20.0", 20)])
def test_a_scenario_reads_N_as_its_loop_file_does(text, value):
    """One rule (issue 26, item 2): a scenario's values are read by the loop-file reader,
    so ``N=1e2`` (refused by the scenarios' own parser before) is 100 in both."""
    sc = scenarios.get("example-3.6")
    assert sc.resolve([f"N={text}"])["N"] == value
    assert sc.file.loop([f"N={text}"]).timing.N == value


@pytest.mark.parametrize("text,value", [("1", 1.0), ("-2.5", -2.5), (".5", 0.5),
                                        ("1.", 1.0), ("1e-3", 1e-3), ("+3E2", 300.0),
                                        (" 0.25 ", 0.25)])
def test_ascii_reals_still_parse(text, value):
    sc = scenarios.get("example-3.6")
    assert sc.resolve([f"k={text}"])["k"] == value
