"""Shared fixtures: the FMUs are built once per test session into a temporary folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Example budgets of the property-based tests (tests/test_fuzz.py): "ci" keeps the suite
# quick; DELAYCOMP_HYPOTHESIS_PROFILE=sweep runs a larger one-off sweep.
settings.register_profile("ci", max_examples=15, deadline=None, derandomize=True,
                          print_blob=True)
settings.register_profile("sweep", max_examples=400, deadline=None, print_blob=True)
settings.load_profile(os.environ.get("DELAYCOMP_HYPOTHESIS_PROFILE", "ci"))

REPO = Path(__file__).resolve().parent.parent


def machine_blas_settings(environ=None) -> list[str]:
    """The machine's ``OPENBLAS_*`` settings as ``NAME=VALUE`` for a child started with a
    cleared environment (``env -i``): some processors need them (other kernels crash or
    compute wrong results there), so a test never drops them (tests/test_machines.py)."""
    environ = os.environ if environ is None else environ
    return [f"{k}={v}" for k, v in sorted(environ.items()) if k.startswith("OPENBLAS_")]


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory) -> Path:
    """Folder with the default FMUs, built by the same code as ``delaycomp build``, and
    the network channel and the time-stamp controller (every FMU of the registry but the
    model templates)."""
    from delaycomp.fmu.build import build_all, build_fmu

    out = tmp_path_factory.mktemp("fmus")
    build_all(out)
    build_fmu("channel", out)
    build_fmu("stamped_controller", out)
    return out


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Never touch the user's FMU cache from a test."""
    monkeypatch.setenv("DELAYCOMP_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "cache"))


_EXIT_STATUS: list[int] = []


def pytest_sessionfinish(session, exitstatus):
    _EXIT_STATUS.append(int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """Leave as the ``delaycomp`` command does (``delaycomp.cli.entry``) once pytest has
    reported: the suite loads pythonfmu FMUs into this process through fmpy, and unloading
    them in the interpreter's teardown corrupts the heap now and then ("corrupted
    double-linked list", SIGABRT after the summary: a green run exiting 134). The exit
    status is pytest's own."""
    import sys

    if "fmpy" in sys.modules and _EXIT_STATUS:
        import atexit

        atexit._run_exitfuncs()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_EXIT_STATUS[-1])


@pytest.fixture(scope="module")
def oms():
    """OMSimulator's install; skipped with the hint when it is absent and not required (a
    ``DELAYCOMP_OMSIMULATOR`` that names no install is an error, not a skip)."""
    import os

    from delaycomp.verify import omsimulator

    try:
        return omsimulator.locate()
    except omsimulator.NotInstalled as exc:
        if os.environ.get(omsimulator.ENV):
            raise
        pytest.skip(f"OMSimulator not found: {exc}")
