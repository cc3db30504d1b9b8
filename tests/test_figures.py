"""The documentation's run figures are today's (issue 27, item 3): each PNG that
``scripts/figures.py`` draws carries the command that drew it and a digest of the
plotting code; a figure whose digest differs from today's ``delaycomp/plotting.py`` was
drawn by other code (redraw it: ``python scripts/figures.py``), and the hero figure at the
top of the README is the plot of the first command's ``run``.
"""

from __future__ import annotations

import importlib.util
import shlex
import zlib
from pathlib import Path

import pytest

from delaycomp import cli

REPO = Path(__file__).resolve().parents[1]


def _load_figures():
    spec = importlib.util.spec_from_file_location("figures_script",
                                                  REPO / "scripts" / "figures.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


figures = _load_figures()


def _chunks(path: Path) -> dict[str, str]:
    """The ``tEXt`` chunks of a PNG, read by hand (a second reader beside PIL's)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, text = 8, {}
    while pos < len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        crc = int.from_bytes(data[pos + 8 + length:pos + 12 + length], "big")
        assert zlib.crc32(kind + body) == crc, (path, kind)
        if kind == b"tEXt":
            key, _, value = body.partition(b"\0")
            text[key.decode("latin-1")] = value.decode("latin-1")
        pos += 12 + length
    return text


@pytest.mark.parametrize("name", sorted(figures.FIGURES))
def test_each_run_figure_is_drawn_by_todays_plotting_code_and_its_command(name):
    path = figures.FIGURES_DIR / name
    text = _chunks(path)
    assert text == {k: v for k, v in figures.png_text(path).items() if k in text}
    assert text.get(figures.COMMAND_KEY) == figures.FIGURES[name], (
        f"{name} was drawn by another command: python scripts/figures.py --only {name}")
    assert text.get(figures.DIGEST_KEY) == figures.plotting_digest(), (
        f"{name} was drawn by other plotting code than today's "
        f"{', '.join(figures.DRAWING_SOURCES)}: python scripts/figures.py --only {name}")


def test_the_hero_figure_is_the_first_commands_run():
    """The README's hero figure is the plot of the first command's ``run``, which
    compares (``--compare``) and writes both CSVs and the plot.

    The first command is the README's, and ``scripts/figures.py`` draws with it."""
    first = figures.readme_first_command((REPO / "README.md").read_text(encoding="utf-8"))
    assert first == figures.FIRST_COMMAND
    run = figures.first_run(first)
    assert figures.FIGURES[figures.HERO] == run
    assert _chunks(figures.FIGURES_DIR / figures.HERO)[figures.COMMAND_KEY] == run
    args = cli._parser().parse_args(shlex.split(run)[1:])
    assert args.command == "run" and args.compare and args.out and args.plot
    # the folders --out and --plot write to exist when the run starts (neither option
    # creates one): made earlier in the first command
    for path in (args.out, args.plot):
        folder = path.parent.as_posix()
        assert folder == "." or f"mkdir -p {folder} && " in first.split(run)[0], folder


def test_the_digest_follows_the_plotting_code(tmp_path):
    """Any change of a drawing source's code changes the digest; line ends, comments and
    docstrings do not."""
    for rel in figures.DRAWING_SOURCES:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes((REPO / rel).read_bytes())
    today = figures.plotting_digest(tmp_path)
    assert today == figures.plotting_digest()
    source = tmp_path / figures.DRAWING_SOURCES[0]
    text = source.read_bytes()
    source.write_bytes(text.replace(b"\n", b"\r\n"))
    assert figures.plotting_digest(tmp_path) == today
    source.write_bytes(text + b"# one more line\n")
    assert figures.plotting_digest(tmp_path) == today
    source.write_bytes(text.replace(b'"""', b'"""Reworded. ', 1))
    assert figures.plotting_digest(tmp_path) == today
    source.write_bytes(text + b"LINEAR_RATIO = 5.0\n")
    assert figures.plotting_digest(tmp_path) != today


def test_first_run_reads_the_readme_form():
    """``readme_first_command`` finds the first sh block's line (as tests/test_docs.py),
    ``first_run`` its ``run``."""
    text = f"# x\n\n```sh\n{figures.FIRST_COMMAND}\n```\n\n```sh\nother\n```\n"
    assert figures.readme_first_command(text) == figures.FIRST_COMMAND
    assert figures.first_run(figures.FIRST_COMMAND).startswith("delaycomp run example-3.6 ")
    with pytest.raises(ValueError, match="no single `delaycomp run`"):
        figures.first_run("delaycomp build --out build/fmus")


def test_the_wheel_smoke_runs_the_first_commands_run_as_typed():
    """``.ci/wheel-smoke`` runs the first command's ``build`` and ``run`` as a user
    types them (from the installed wheel) and checks both CSVs."""
    smoke = (REPO / ".ci" / "wheel-smoke").read_text(encoding="utf-8")
    build = next(part.strip() for part in figures.FIRST_COMMAND.split("&&")
                 if "delaycomp build" in part)
    assert f'"$dc" {build.removeprefix(".venv/bin/delaycomp ")}' in smoke
    run = figures.first_run(figures.FIRST_COMMAND)
    assert f'\nmkdir -p out\n"$dc" {run.removeprefix("delaycomp ")}\n' in smoke
    assert 'read("out/example-3.6.uncompensated.csv")' in smoke
