"""mypy on the package as it installs: ``orchestrator/`` and ``fmus/`` as
``delaycomp.orchestrator`` and ``delaycomp.fmus``.

The repository keeps ``orchestrator/``, ``fmus/`` and ``reference/`` at its top; setuptools
installs them inside the namespace (``package-dir`` in ``pyproject.toml``) and, in a
checkout, ``delaycomp.layout``'s import finder maps the names. mypy runs no import hooks,
so run on the checkout as it stands it would see ``delaycomp.orchestrator.*`` as a module
it cannot find. This script assembles, in a temporary folder, the tree that installs: a
``delaycomp/`` of links to the package's files, with ``orchestrator/`` and ``fmus/`` linked
in as its subpackages, and ``reference/`` with its ``__init__.py`` alone (its scripts run
as files and import their shared module by its bare name: they are not the package's
code). mypy checks that tree with ``pyproject.toml``'s ``[tool.mypy]``, each module once,
under the name it imports by; its messages name the repository's files. The exit status is
mypy's. Usage, from anywhere::

    python scripts/typecheck.py                     # what CI runs (.ci/run)
    python scripts/typecheck.py orchestrator/fmu.py # some files only; mypy's options pass

Links where the platform makes them, copies elsewhere (links need a privilege on Windows).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "delaycomp"
#: folders at the repository's top that install as subpackages -> the files mypy checks
#: there (``None``: all of them)
BESIDE: dict[str, tuple[str, ...] | None] = {
    "orchestrator": None,
    "fmus": None,
    "reference": ("__init__.py",),
}
SKIP = {"__pycache__"}


def place(source: Path, target: Path) -> None:
    """``target`` as ``source`` (a file or a folder): a link, or a copy where links fail."""
    try:
        target.symlink_to(source, target_is_directory=source.is_dir())
    except OSError:
        if source.is_dir():
            shutil.copytree(source, target, ignore=shutil.ignore_patterns(*SKIP))
        else:
            shutil.copy2(source, target)


def assemble(tree: Path) -> None:
    """The package as it installs, under ``tree``."""
    package = tree / PACKAGE
    package.mkdir()
    for entry in sorted((ROOT / PACKAGE).iterdir()):
        if entry.name not in SKIP:
            place(entry, package / entry.name)
    for folder, files in BESIDE.items():
        if (package / folder).exists():
            raise SystemExit(f"{PACKAGE}/{folder} exists: it is the top-level {folder}/ "
                             "installed there; remove it")
        if files is None:
            place(ROOT / folder, package / folder)
            continue
        (package / folder).mkdir()
        for name in files:
            place(ROOT / folder / name, package / folder / name)


def to_tree(arg: str) -> str:
    """A command-line argument naming a file or folder of the repository, as the tree's;
    any other argument as it is."""
    path = Path(arg)
    if arg.startswith("-") or not path.exists():
        return arg
    try:
        rel = path.resolve().relative_to(ROOT)
    except ValueError:
        return arg
    if rel.parts and rel.parts[0] in BESIDE:
        rel = Path(PACKAGE, *rel.parts)
    return str(rel)


def from_tree(line: str, tree: Path) -> str:
    """mypy's line with the tree's paths as the repository's."""
    line = line.replace(str(tree) + os.sep, "")
    beside = "|".join(map(re.escape, BESIDE))
    return re.sub(rf"(^|[\s\"'(]){PACKAGE}[/\\]({beside})(?=[/\\])", r"\1\2", line)


def main(argv: list[str]) -> int:
    with tempfile.TemporaryDirectory(prefix="delaycomp-typecheck-") as tmp:
        tree = Path(tmp)
        assemble(tree)
        # the files: [tool.mypy]'s ("delaycomp", the tree's package) unless named here
        command = [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
                   "--cache-dir", str(ROOT / ".mypy_cache"), *map(to_tree, argv)]
        process = subprocess.Popen(command, cwd=tree, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, text=True)
        assert process.stdout is not None  # stdout=PIPE
        for line in process.stdout:
            sys.stdout.write(from_tree(line, tree))
        return process.wait()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
