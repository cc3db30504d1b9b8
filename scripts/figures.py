"""Redraw the documentation's figures that are a ``delaycomp run ... --plot``, each with
exactly its command, and stamp into each PNG the command that drew it and a digest of
the plotting code (``tests/test_figures.py`` fails when either is stale).

The hero figure at the top of the README, ``docs/figures/example-3.6-compare.png``, is
the plot of the README's first command: its ``build`` (into a temporary folder, or the
``--fmu-dir`` given here) and then its ``run`` (``FIRST_RUN``) in that folder, the
plot copied here. The others run from the checkout's root with ``--plot`` into
``docs/figures``, the FMUs from delaycomp's build cache.

Usage (from the checkout, with delaycomp installed)::

    python scripts/figures.py                 # every figure of FIGURES
    python scripts/figures.py --only example-3.6-compare.png --fmu-dir build/fmus

Each PNG gets the text chunks ``delaycomp command`` (the command, as a user types it),
``delaycomp plotting sha256`` (``plotting_digest`` of ``DRAWING_SOURCES``) and
``delaycomp version``, beside matplotlib's ``Software``.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import hashlib
import os
import re
import shlex
import shutil
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FIGURES_DIR = REPO / "docs" / "figures"

#: The first command proposed for the README (issue 27, item 3): the install, the FMUs,
#: a folder for the results (``--out`` and ``--plot`` never create one) and the run of
#: Example 3.6 compensated against uncompensated.
FIRST_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install '.[control]' && "
    ".venv/bin/delaycomp build --out build/fmus && mkdir -p out && "
    ".venv/bin/delaycomp run example-3.6 --fmu-dir build/fmus --set r=0.3 --set u0=4 "
    "--compare --out out/example-3.6.csv --plot out/example-3.6.png")


def first_run(command: str) -> str:
    """The ``delaycomp run`` of a first command (``.venv/bin/`` dropped).

    Examples
    --------
    >>> first_run(FIRST_COMMAND)[:38]
    'delaycomp run example-3.6 --fmu-dir bu'
    """
    runs = [part.strip() for part in command.split("&&")
            if re.match(r"\s*(\.venv/bin/)?delaycomp run ", part)]
    if len(runs) != 1:
        raise ValueError(f"no single `delaycomp run` in {command!r}")
    return re.sub(r"^\.venv/bin/", "", runs[0])


def readme_first_command(text: str) -> str:
    """The README's first command: its first ``sh`` block's line (the regex of
    tests/test_docs.py)."""
    found = re.search(r"```sh\n(.*)\n```", text)
    if found is None:
        raise ValueError("the README has no sh block")
    return found.group(1)


#: the run of the first command: the hero figure
FIRST_RUN = first_run(FIRST_COMMAND)
HERO = "example-3.6-compare.png"

#: figure file (in docs/figures) -> the command that draws it. The hero's runs in a
#: folder holding the first command's build/fmus and out/; the others from the
#: checkout's root.
FIGURES: dict[str, str] = {
    HERO: FIRST_RUN,
    # the paper's Figures 1-3 (README: Example 3.6)
    "example-3.6-fig1.png": "delaycomp run example-3.6 --set r=0.1 --set mode=uncompensated "
                            "--plot docs/figures/example-3.6-fig1.png",
    "example-3.6-fig2.png": "delaycomp run example-3.6 --set r=0.3 --set mode=uncompensated "
                            "--plot docs/figures/example-3.6-fig2.png",
    "example-3.6-fig3.png": "delaycomp run example-3.6 --set r=0.3 --set u0=4 "
                            "--plot docs/figures/example-3.6-fig3.png",
    # the paper's other examples at their defaults (README: docs/figures/<scenario>.png)
    **{f"{name}.png": f"delaycomp run {name} --plot docs/figures/{name}.png"
       for name in ("example-2.4", "example-3.8", "corollary-3.7", "corollary-4.1",
                    "proposition-4.2")},
    # the tutorial's loop file, both modes
    "tutorial-cart.png": "delaycomp run docs/examples/cart.toml --compare "
                         "--plot docs/figures/tutorial-cart.png",
}

#: the code that draws a run's figure (the CLI's ``--plot`` calls
#: ``delaycomp.plotting.plot_result``, which draws with matplotlib alone)
DRAWING_SOURCES = ("delaycomp/plotting.py",)

COMMAND_KEY = "delaycomp command"
DIGEST_KEY = "delaycomp plotting sha256"
VERSION_KEY = "delaycomp version"


def plotting_digest(root: Path = REPO) -> str:
    """SHA-256 of the code of ``DRAWING_SOURCES``: each file's path and its syntax tree
    without docstrings (``ast.dump``), so a change of what is drawn changes it and a
    change of the words around it (docstrings, comments, layout, line ends) does not."""
    digest = hashlib.sha256()
    for rel in DRAWING_SOURCES:
        tree = ast.parse((root / rel).read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            body = getattr(node, "body", None)
            if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                    and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]  # type: ignore[attr-defined]
        digest.update(rel.encode() + b"\0" + ast.dump(tree).encode() + b"\0")
    return digest.hexdigest()


def png_text(path: Path) -> dict[str, str]:
    """The text chunks (``tEXt``, ``zTXt``, ``iTXt``) of a PNG."""
    from PIL import Image

    with Image.open(path) as image:
        image.load()
        return {str(k): str(v) for k, v in getattr(image, "text", {}).items()}


def stamp(path: Path, command: str) -> None:
    """Add the command, the plotting digest and delaycomp's version to the PNG at
    ``path`` (its pixels and matplotlib's own chunks kept)."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    import delaycomp

    with Image.open(path) as image:
        image.load()
        info = PngInfo()
        for key, value in getattr(image, "text", {}).items():
            if key not in (COMMAND_KEY, DIGEST_KEY, VERSION_KEY):
                info.add_text(key, value)
        info.add_text(COMMAND_KEY, command)
        info.add_text(DIGEST_KEY, plotting_digest())
        info.add_text(VERSION_KEY, delaycomp.__version__)
        tmp = path.with_name(path.name + ".part")
        image.save(tmp, format="PNG", pnginfo=info)
    tmp.replace(path)


@contextlib.contextmanager
def _cwd(folder: Path):
    before = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)


def _delaycomp(command: str) -> None:
    """Run ``delaycomp ...`` in this process, as the shell would; fail loudly."""
    from delaycomp import cli

    argv = shlex.split(command)
    assert argv[0] == "delaycomp", command
    code = cli.main(argv[1:])
    if code != 0:
        raise SystemExit(f"`{command}` failed with exit status {code}")


def draw_hero(fmu_dir: Path | None) -> Path:
    """The first command's ``build`` (unless ``fmu_dir`` has it) and ``run`` in a
    temporary folder; its plot copied to docs/figures with the stamp."""
    target = FIGURES_DIR / HERO
    with tempfile.TemporaryDirectory(prefix="delaycomp-figures-") as tmp:
        work = Path(tmp)
        build = work / "build" / "fmus"
        build.parent.mkdir()
        if fmu_dir is not None:
            build.symlink_to(fmu_dir.resolve(), target_is_directory=True)
        (work / "out").mkdir()
        with _cwd(work):
            if fmu_dir is None:
                _delaycomp("delaycomp build --out build/fmus")
            _delaycomp(FIRST_RUN)
        plot = work / shlex.split(FIRST_RUN)[shlex.split(FIRST_RUN).index("--plot") + 1]
        shutil.copyfile(plot, target)
    stamp(target, FIRST_RUN)
    return target


def draw(name: str) -> Path:
    """A figure other than the hero: its command from the checkout's root."""
    target = FIGURES_DIR / name
    with _cwd(REPO):
        _delaycomp(FIGURES[name])
    stamp(target, FIGURES[name])
    return target


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", action="append", choices=sorted(FIGURES), default=None,
                   help="redraw this figure only (repeatable)")
    p.add_argument("--fmu-dir", type=Path, default=None,
                   help="the first command's build/fmus, built already (default: built "
                        "into a temporary folder)")
    args = p.parse_args(argv)
    for name in args.only or list(FIGURES):
        path = draw_hero(args.fmu_dir) if name == HERO else draw(name)
        print(f"{path.relative_to(REPO)}: {FIGURES[name]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
