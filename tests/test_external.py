"""The one decision on tools from outside the wheel (``tests/external.py``): an absent tool
skips with its reason, a required absent tool fails, a present one is handed over."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from .external import REQUIRE, TOOLS, Absent, need, required

REPO = Path(__file__).resolve().parent.parent
#: a name no machine has on PATH
NOWHERE = "/nonexistent-delaycomp-test"


def _gone() -> None:
    raise Absent("looked in the moon")


def test_an_absent_tool_skips_with_its_reason_and_how_to_get_it(monkeypatch):
    monkeypatch.delenv(REQUIRE, raising=False)
    monkeypatch.setenv("PATH", NOWHERE)
    with pytest.raises(pytest.skip.Exception) as info:
        need("wine", what="the win64 binaries run")
    assert str(info.value) == ("wine not found (wine is not on PATH): `apt-get install wine "
                               "wine64`, or scripts/install_platform_tools.sh; the win64 "
                               "binaries run not checked")


@pytest.mark.parametrize("listed", ["wine", "qemu-aarch64,wine", " all "])
def test_a_required_absent_tool_fails(monkeypatch, listed):
    monkeypatch.setenv(REQUIRE, listed)
    monkeypatch.setenv("PATH", NOWHERE)
    with pytest.raises(pytest.fail.Exception) as info:
        need("wine")
    assert str(info.value).startswith("wine not found (wine is not on PATH): ")
    assert str(info.value).endswith(f"[required here: {REQUIRE}={listed}]")


def test_a_tools_own_variable_requires_it(monkeypatch):
    """``DELAYCOMP_OMSIMULATOR`` (CI sets it) makes OMSimulator's absence a failure; the
    exception the finder raises is named by the caller."""
    monkeypatch.delenv(REQUIRE, raising=False)
    monkeypatch.setenv("DELAYCOMP_OMSIMULATOR", NOWHERE)

    def locate():
        raise FileNotFoundError(f"{NOWHERE} holds no OMSimulator")

    with pytest.raises(pytest.fail.Exception, match="DELAYCOMP_OMSIMULATOR is set"):
        need("omsimulator", locate, (FileNotFoundError,))
    monkeypatch.delenv("DELAYCOMP_OMSIMULATOR")
    with pytest.raises(pytest.skip.Exception, match=f"^omsimulator not found .{NOWHERE} holds"):
        need("omsimulator", locate, (FileNotFoundError,))


def test_a_present_tool_is_handed_over_and_other_errors_propagate(monkeypatch):
    monkeypatch.setenv(REQUIRE, "all")
    assert need("gcc", lambda: "/usr/bin/gcc") == "/usr/bin/gcc"
    with pytest.raises(ZeroDivisionError):  # a bug in finding is no absence
        need("gcc", lambda: 1 / 0)
    with pytest.raises(KeyError, match="knows no tool 'tcc'"):
        need("tcc")


def test_only_named_tools_are_required():
    env = {REQUIRE: "wine", "DELAYCOMP_OMSIMULATOR": ""}
    assert [n for n in TOOLS if required(n, env)] == ["wine"]
    assert all(required(n, {REQUIRE: "all"}) for n in TOOLS)
    assert not any(required(n, {}) for n in TOOLS)


def test_pytests_summary_names_the_skip_and_the_failure(tmp_path):
    """Through pytest itself (a child session with ``-ra``): the absent tool is reported as
    SKIPPED with its line, the required one as FAILED, and the exit status is 1."""
    (tmp_path / "test_tools.py").write_text(textwrap.dedent(f'''
        from tests.external import need, Absent

        def gone():
            raise Absent("not here")

        def test_optional(monkeypatch):
            monkeypatch.delenv("{REQUIRE}", raising=False)
            need("clang", gone)

        def test_required(monkeypatch):
            monkeypatch.setenv("{REQUIRE}", "clang")
            need("clang", gone)
    '''))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-ra", "-p", "no:cacheprovider",
                           "-p", "no:xdist", str(tmp_path / "test_tools.py")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stdout
    lines = proc.stdout.splitlines()
    assert any(ln.startswith("SKIPPED [1] ") and ln.endswith(
        "clang not found (not here): `apt-get install clang`, or "
        "scripts/install_platform_tools.sh") for ln in lines), proc.stdout
    assert any(ln.startswith("FAILED test_tools.py::test_required - Failed: clang not found")
               for ln in lines), proc.stdout
    assert "clang not found (not here): `apt-get install clang`, or " \
           "scripts/install_platform_tools.sh [required here: DELAYCOMP_REQUIRE=clang]" \
           in lines, proc.stdout
    assert lines[-1].startswith("1 failed, 1 skipped")


@pytest.fixture(scope="module")
def _cache_seen_by_a_module_fixture() -> str | None:
    return os.environ.get("DELAYCOMP_CACHE_DIR")


def test_module_fixtures_build_into_the_sessions_cache_not_the_users(
        _cache_seen_by_a_module_fixture, tmp_path_factory):
    """The module fixtures that take FMUs from the build cache (``native_fmu_path``) run
    before any function fixture: the session's cache is set for them too, never the
    user's ``~/.cache/delaycomp``."""
    from .conftest import session_root

    want = str(session_root(tmp_path_factory) / "cache")
    assert _cache_seen_by_a_module_fixture == want
    assert os.environ.get("DELAYCOMP_CACHE_DIR") == want
