"""``run --fmu-dir DIR`` after ``build --out DIR`` (issue 50, item 2): the run takes the
FMUs that the build wrote there, native or Python, and builds none (``-v`` names each file
it took, ``cache hit: IDENT (DIR/FILE.fmu)``, and no ``building`` line); an FMU there that
is stale (another delaycomp version, other sources) or of the wrong kind (native where
``--python`` runs, Python where ``--native`` or ``--fmi 3`` runs, another FMI version,
other dimensions) is one line naming the file and what to do, exit status 2, no
traceback, and nothing built elsewhere instead."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import delaycomp
from delaycomp import api
from delaycomp.paper import scenarios

from .external import need

pytestmark = pytest.mark.fmu

#: the README's first command's run, after its build (the loop's three FMUs)
README_RUN = ["--set", "r=0.3", "--set", "u0=4", "--compare"]
FILES = ("DelaycompPlantLTI.fmu", "DelaycompDelay.fmu", "DelaycompControllerLTI.fmu")
IDENTS = [name.removesuffix(".fmu") for name in FILES]


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "delaycomp", *map(str, args)],
                          capture_output=True, text=True, timeout=900, cwd=cwd)


@pytest.fixture(scope="module")
def native_out(tmp_path_factory) -> Path:
    """What ``delaycomp build --out DIR`` writes for the LTI loop where a C compiler is:
    the same call (``build_native``), without the scenarios' archives."""
    from delaycomp.fmu.native import NativeBuildError, build_native, compiler

    need("cc", compiler, (NativeBuildError,), "run --fmu-dir DIR with native FMUs")
    out = tmp_path_factory.mktemp("native-out")
    build_native(out)
    return out


def _copy(src: Path, dest: Path) -> Path:
    """The loop's three FMUs of ``src`` in a fresh folder ``dest`` (the fixtures stay
    read only)."""
    dest.mkdir()
    for name in FILES:
        shutil.copy2(src / name, dest / name)
    return dest


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in folder.rglob("*")}


def _one_line_error(proc, folder: Path) -> str:
    """The run's one line (exit status 2, no traceback), nothing built for it."""
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert not (folder / "native").exists()  # nothing built elsewhere instead
    return lines[0]


def _rewrite_config(path: Path, **changes) -> None:
    """``path`` with ``changes`` in its build configuration (``None``: the key removed)."""
    with zipfile.ZipFile(path) as zin:
        items = [(item, zin.read(item)) for item in zin.infolist()]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zout:
        for item, data in items:
            if item.filename == "resources/delaycomp_fmu.json":
                cfg = json.loads(data)
                for key, value in changes.items():
                    if value is None:
                        cfg.pop(key, None)
                    else:
                        cfg[key] = value
                data = json.dumps(cfg, sort_keys=True).encode()
            zout.writestr(item, data)


def _config(path: Path) -> dict:
    with zipfile.ZipFile(path) as zf:
        return json.loads(zf.read("resources/delaycomp_fmu.json"))


# -- no second build -----------------------------------------------------------------------
def test_run_takes_the_native_fmus_that_build_out_wrote(native_out, tmp_path):
    """The README's first command's run, after its build: no build at all, the three
    native FMUs of DIR run (``-v``: a cache hit for each, in DIR), DIR unchanged."""
    folder = _copy(native_out, tmp_path / "fmus")
    assert all(_config(folder / name)["native"] for name in FILES)
    before = _snapshot(folder)
    out = tmp_path / "out" / "example-3.6.csv"
    out.parent.mkdir()
    proc = cli("run", "-v", "example-3.6", "--fmu-dir", folder, *README_RUN, "--out", out,
               "--plot", tmp_path / "out" / "example-3.6.png")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert not [line for line in lines if line.startswith("building")], proc.stderr
    hits = sorted(line for line in lines if line.startswith("cache hit:"))
    assert hits == sorted(f"cache hit: {ident} ({folder / name})"
                          for ident, name in zip(IDENTS, FILES)), proc.stderr
    assert _snapshot(folder) == before  # nothing built, nothing written there
    assert out.exists() and (tmp_path / "out" / "example-3.6.uncompensated.csv").exists()


def test_run_takes_the_python_fmus_that_build_out_wrote(fmu_dir, tmp_path):
    """``build --out DIR`` without a C compiler (or with ``--python``) writes the Python
    FMUs: the default run takes them, builds no native ones, and says so under ``-v``."""
    folder = _copy(fmu_dir, tmp_path / "fmus")
    before = _snapshot(folder)
    proc = cli("run", "-v", "example-3.6", "--fmu-dir", folder, "--stop-time", "2")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert not [line for line in lines if line.startswith("building")], proc.stderr
    assert f"the Python FMUs run this loop: {folder} holds Python ones" in lines
    hits = sorted(line for line in lines if line.startswith("cache hit:"))
    assert hits == sorted(f"cache hit: {ident} ({folder / name})"
                          for ident, name in zip(IDENTS, FILES)), proc.stderr
    assert _snapshot(folder) == before
    assert "note:" not in proc.stderr


def test_choose_fmus_takes_the_files_of_fmu_dir(native_out, fmu_dir):
    """The API's choice (``choose_fmus``, which ``run`` and the command line go through):
    the native files of the folder, by instance; the Python ones as ``None`` (run from the
    folder), no native twin built."""
    sc = scenarios.get("example-3.6")
    loop = sc.make(sc.resolve([]))
    names = {"plant": FILES[0], "meas_delay": FILES[1], "controller": FILES[2],
             "input_delay": FILES[1]}
    assert api.choose_fmus(loop, "auto", native_out) == (
        {inst: native_out / name for inst, name in names.items()}, None)
    assert api.choose_fmus(loop, "native", native_out)[0] == {
        inst: native_out / name for inst, name in names.items()}
    assert api.choose_fmus(loop, "auto", fmu_dir) == (None, None)
    assert not (native_out / "native").exists() and not (fmu_dir / "native").exists()


# -- stale ---------------------------------------------------------------------------------
STALE = {
    "other-version": ({"version": "0.0.0"},
                      f"was built by delaycomp '0.0.0', this is '{delaycomp.__version__}'"),
    "other-sources": ({"sources": "0123456789ab"},
                      "is stale: it was built from other sources than this delaycomp "
                      f"{delaycomp.__version__}'s"),
    "no-sources": ({"sources": None},  # built before FMUs recorded their sources
                   "is stale: it was built from other sources than this delaycomp "
                   f"{delaycomp.__version__}'s"),
}


@pytest.mark.parametrize("kind", ["native", "python"])
@pytest.mark.parametrize("case", sorted(STALE))
def test_a_stale_fmu_in_fmu_dir_is_one_line(native_out, fmu_dir, tmp_path, kind, case):
    changes, reason = STALE[case]
    folder = _copy(native_out if kind == "native" else fmu_dir, tmp_path / "fmus")
    stale = folder / "DelaycompDelay.fmu"
    _rewrite_config(stale, **changes)
    out = tmp_path / "run.csv"
    proc = cli("run", "example-3.6", "--fmu-dir", folder, "--stop-time", "1", "--out", out)
    line = _one_line_error(proc, folder)
    assert line == (f"delaycomp: error: {stale}: {reason} (rebuild the folder: delaycomp "
                    f"build --out {folder}, or delete the file)")
    assert not out.exists()


# -- the wrong kind ------------------------------------------------------------------------
def test_a_native_fmu_where_python_ones_run_is_one_line(native_out, tmp_path):
    folder = _copy(native_out, tmp_path / "fmus")
    line = _one_line_error(cli("run", "example-3.6", "--python", "--fmu-dir", folder,
                               "--stop-time", "1"), folder)
    assert line == (f"delaycomp: error: {folder / FILES[0]}: is a native FMU, --python runs "
                    "Python ones (run without --python to use it, or rebuild the folder: "
                    f"delaycomp build --python --out {folder})")


@pytest.mark.parametrize("flag", [["--native"], ["--fmi", "3"]], ids=" ".join)
def test_a_python_fmu_where_native_ones_run_is_one_line(fmu_dir, tmp_path, flag):
    folder = _copy(fmu_dir, tmp_path / "fmus")
    line = _one_line_error(cli("run", "example-3.6", *flag, "--fmu-dir", folder,
                               "--stop-time", "1"), folder)
    what = " ".join(flag)
    assert line == (f"delaycomp: error: {folder / FILES[0]}: is a Python FMU, {what} runs "
                    f"native ones (run without {what} to use it, or rebuild the folder: "
                    f"delaycomp build {what} --out {folder})")


def test_an_fmi_2_fmu_where_fmi_3_ones_run_is_one_line(native_out, tmp_path):
    folder = _copy(native_out, tmp_path / "fmus")
    line = _one_line_error(cli("run", "example-3.6", "--fmi", "3", "--fmu-dir", folder,
                               "--stop-time", "1"), folder)
    assert line == (f"delaycomp: error: {folder / FILES[0]}: is an FMI 2.0 FMU, this run "
                    "needs FMI 3.0 (run without --fmi 3 to use it, or rebuild the folder: "
                    f"delaycomp build --fmi 3 --out {folder})")


def test_an_fmi_3_fmu_where_fmi_2_ones_run_is_one_line(native_out, tmp_path):
    from delaycomp.fmu.native import build_native_fmu

    folder = _copy(native_out, tmp_path / "fmus")
    build_native_fmu("delay", folder, fmi=3)  # over the FMI 2.0 one, as build --fmi 3 does
    assert _config(folder / "DelaycompDelay.fmu")["fmi"] == 3
    line = _one_line_error(cli("run", "example-3.6", "--fmu-dir", folder, "--stop-time",
                               "1"), folder)
    assert line == (f"delaycomp: error: {folder / 'DelaycompDelay.fmu'}: is an FMI 3.0 FMU, "
                    "this run needs FMI 2.0 (--fmi 3 runs it, or rebuild the folder: "
                    f"delaycomp build --out {folder})")


def test_python_and_native_fmus_of_one_loop_are_one_line(native_out, fmu_dir, tmp_path):
    """The default takes the kind of the folder's FMUs: a folder that holds both for one
    loop is an error naming the odd one out, not a silent mix."""
    folder = _copy(native_out, tmp_path / "fmus")
    shutil.copy2(fmu_dir / "DelaycompDelay.fmu", folder / "DelaycompDelay.fmu")
    line = _one_line_error(cli("run", "example-3.6", "--fmu-dir", folder, "--stop-time",
                               "1"), folder)
    assert line == (f"delaycomp: error: {folder / 'DelaycompDelay.fmu'}: is a Python FMU "
                    "beside native ones of this loop (rebuild the folder: delaycomp build "
                    f"--out {folder}, or delete the file)")


@pytest.mark.parametrize("kind", ["native", "python"])
def test_an_fmu_of_other_dimensions_is_one_line(native_out, fmu_dir, tmp_path, kind):
    folder = _copy(native_out if kind == "native" else fmu_dir, tmp_path / "fmus")
    _rewrite_config(folder / "DelaycompDelay.fmu", n=2)
    line = _one_line_error(cli("run", "example-3.6", "--fmu-dir", folder, "--stop-time",
                               "1"), folder)
    assert line == (f"delaycomp: error: {folder / 'DelaycompDelay.fmu'}: was built for "
                    "{'n': 2}, this loop needs {'n': 1}")


# -- the README's first command, as typed --------------------------------------------------
@pytest.mark.slow
def test_the_readme_first_command_builds_the_fmus_once(tmp_path):
    """``delaycomp build --out build/fmus`` then ``delaycomp run example-3.6 --fmu-dir
    build/fmus ...``: the run builds nothing (under ``-v`` no ``building`` line) and takes
    the build's three FMUs."""
    from delaycomp.fmu.native import NativeBuildError, compiler

    need("cc", compiler, (NativeBuildError,), "the README's first command, native")
    built = cli("build", "--out", "build/fmus", cwd=tmp_path)
    assert built.returncode == 0, built.stderr
    (tmp_path / "out").mkdir()
    proc = cli("run", "-v", "example-3.6", "--fmu-dir", "build/fmus", *README_RUN, "--out",
               "out/example-3.6.csv", "--plot", "out/example-3.6.png", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert not [line for line in lines if line.startswith("building")], proc.stderr
    hits = sorted(line for line in lines if line.startswith("cache hit:"))
    assert hits == sorted(f"cache hit: {ident} ({Path('build/fmus') / name})"
                          for ident, name in zip(IDENTS, FILES)), proc.stderr
    assert not (tmp_path / "build" / "fmus" / "native").exists()
