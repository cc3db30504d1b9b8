"""Shared fixtures: the FMUs are built once per test session into a temporary folder."""

from __future__ import annotations

import contextlib
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


def session_root(tmp_path_factory) -> Path:
    """The folder of this test session that every pytest-xdist worker shares (each worker's
    own ``getbasetemp()`` lies in it); without workers, the session's ``getbasetemp()``."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def built_once(tmp_path_factory, name: str, build) -> Path:
    """``session_root/name``, filled by ``build(folder)`` once per test session whichever
    worker asks first (the others wait on a lock, then take the folder as it is); a build
    that fails leaves no folder, so the next asker builds again and fails the same way."""
    import shutil

    from delaycomp.tmpfiles import build_lock

    out = session_root(tmp_path_factory) / name
    with build_lock(out):
        if not out.is_dir():
            part = out.with_name(f".{name}.{os.getpid()}.part")
            shutil.rmtree(part, ignore_errors=True)
            part.mkdir()
            build(part)
            part.rename(out)
    return out


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory) -> Path:
    """Folder with the default FMUs, built by the same code as ``delaycomp build``, and
    the network channel and the time-stamp controller (every FMU of the registry but the
    model templates); built once per session, shared by every worker (read only)."""
    from delaycomp.fmu.build import build_all, build_fmu

    def build(out: Path) -> None:
        build_all(out)
        build_fmu("channel", out)
        build_fmu("stamped_controller", out)

    return built_once(tmp_path_factory, "fmus", build)


@pytest.fixture(scope="session")
def native_dir() -> Path:
    """The folder of the session's native build cache (``native_fmu_dir``), holding the
    default native FMU of every kind with a native twin (the LTI loop's three, the network
    channel, the time-stamp controller) under its own name, ``<modelIdentifier>.fmu``: the
    native twins of ``fmu_dir``."""
    from delaycomp.fmu.build import DEFAULT_CONFIG
    from delaycomp.fmu.native import NATIVE_KINDS, native_fmu_dir, native_fmu_path

    for kind in NATIVE_KINDS:
        native_fmu_path(kind, DEFAULT_CONFIG[kind])
    return native_fmu_dir()


@pytest.fixture(scope="session")
def chost(tmp_path_factory) -> Path:
    """The C closed-loop host (``fmus/native/host/host.c``) for this machine, compiled once
    per test session for every worker (``delaycomp.fmu.host.compile_host``)."""
    from delaycomp.fmu.host import compile_host

    return built_once(tmp_path_factory, "chost", lambda out: compile_host(out / "host")) / "host"


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Never touch the user's FMU cache from a test: the session's own, one for every
    worker (the caches lock each build: one worker builds an FMU, the others wait for it),
    for the whole session, so the module fixtures that take FMUs from the cache
    (``native_fmu_path``) find it set too."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DELAYCOMP_CACHE_DIR", str(session_root(tmp_path_factory) / "cache"))
        yield


@pytest.fixture(scope="session", autouse=True)
def _this_platform_only():
    """Native FMUs for this machine's platform alone (``DELAYCOMP_PLATFORMS=""``), for the
    whole session, its module and session fixtures included: where the cross compilers
    are installed every native build would compile each FMU three times, for binaries no
    test but the platform tests reads. The tests marked ``platforms``
    (``tests/test_platforms.py``) build every platform, as ``delaycomp build`` does
    (``every_platform``)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DELAYCOMP_PLATFORMS", "")
        yield


@pytest.fixture(autouse=True)
def _platforms_when_marked(request, monkeypatch):
    """A test marked ``platforms`` builds every platform (``_this_platform_only``)."""
    if request.node.get_closest_marker("platforms") is not None:
        monkeypatch.delenv("DELAYCOMP_PLATFORMS", raising=False)


@contextlib.contextmanager
def every_platform():
    """Native builds for every platform whose compiler is here, while the block runs (for
    the module fixtures of the tests marked ``platforms``)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv("DELAYCOMP_PLATFORMS", raising=False)
        yield


def pytest_configure(config):
    """The programs the tests start get SIGINT's and SIGHUP's default actions, as a
    terminal's programs do, also where pytest itself was started with them ignored (a
    script's background job ignores SIGINT, ``nohup`` SIGHUP): they would inherit the
    ignored signals, and the tests that interrupt them (Ctrl-C, a closed terminal) would
    wait for them in vain. Set before pytest-xdist starts its workers, which inherit it."""
    import signal

    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)


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
    ``DELAYCOMP_OMSIMULATOR`` that names no install fails: ``tests/external.py``)."""
    from delaycomp.verify import omsimulator

    from .external import need

    return need("omsimulator", omsimulator.locate, (omsimulator.NotInstalled,))


def _sigint_state() -> tuple:
    """This process's SIGINT disposition: Python's handler, and whether the kernel has it
    ignored or blocked (a library loaded into the process can do either)."""
    import signal

    bits = []
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(("SigBlk:", "SigIgn:")):
                    bits.append(bool(int(line.split()[1], 16) & (1 << (signal.SIGINT - 1))))
    except OSError:  # not Linux
        pass
    return (signal.getsignal(signal.SIGINT), *bits)


@pytest.fixture(autouse=True)
def _sigint_unchanged():
    """A test leaves SIGINT as it found it: the programs later tests start inherit an
    ignored or blocked SIGINT, and their Ctrl-C tests then hang (whichever test file a
    pytest-xdist worker happens to run after the one that changed it)."""
    before = _sigint_state()
    yield
    after = _sigint_state()
    assert after == before, f"this test changed SIGINT (handler, blocked, ignored): " \
                            f"{before} -> {after}"


@pytest.fixture(autouse=True)
def _alone_when_marked(request, tmp_path_factory):
    """Under pytest-xdist, a test marked ``alone`` (it measures wall time against a bound,
    or needs the cores to itself) runs while no other worker runs a test: it takes the
    session's lock file exclusively, every other test takes it shared. Without workers
    there is nothing to wait for."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    import fcntl

    lock = session_root(tmp_path_factory) / ".alone.lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        alone = request.node.get_closest_marker("alone") is not None
        fcntl.flock(fd, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        yield
    finally:
        os.close(fd)  # releases the lock
