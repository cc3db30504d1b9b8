"""Shared fixtures: the FMUs are built once per test session into a temporary folder."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory) -> Path:
    """Folder with the default FMUs, built by the same code as ``delaycomp build``."""
    from delaycomp.build import build_all

    out = tmp_path_factory.mktemp("fmus")
    build_all(out)
    return out


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Never touch the user's FMU cache from a test."""
    monkeypatch.setenv("DELAYCOMP_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "cache"))
