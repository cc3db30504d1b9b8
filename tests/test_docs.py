"""The documentation's code runs and says what the pages say it prints."""

from __future__ import annotations

import re
import shutil

from .conftest import REPO

TUTORIAL = REPO / "docs" / "tutorial.md"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_tutorial_code_runs_and_prints_what_the_page_shows(tmp_path, monkeypatch, capsys):
    text = TUTORIAL.read_text(encoding="utf-8")
    blocks = [b for b in _python_blocks(text) if "api.run" in b or "figure(" in b]
    assert len(blocks) == 2  # the comparison, then the figure
    shutil.copytree(REPO / "docs" / "examples", tmp_path / "docs" / "examples")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(blocks[0], "tutorial-1", "exec"), namespace)
    printed = dict(line.split() for line in capsys.readouterr().out.splitlines())
    shown = dict(line.split() for line in
                 re.search(r"prints\n\n```text\n(.*?)```", text, flags=re.S).group(1)
                 .splitlines())
    assert printed.keys() == shown.keys() == {"compensated", "uncompensated"}
    # dead-beat: the compensated cart is at the origin to round-off (|x0| = 1 scale)
    assert abs(float(printed["compensated"])) < 1e-12
    assert abs(float(shown["compensated"])) < 1e-12
    # the uncompensated swing is an exact ZOH computation: the page's digits, to round-off
    assert abs(float(printed["uncompensated"]) - float(shown["uncompensated"])) < 1e-9
    exec(compile(blocks[1], "tutorial-2", "exec"), namespace)
    assert (tmp_path / "cart.png").stat().st_size > 0


def test_every_page_in_the_nav_exists():
    nav = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    pages = re.findall(r"([\w/.-]+\.md)\s*$", nav, flags=re.M)
    assert len(pages) > 15
    missing = [p for p in pages if not (REPO / "docs" / p).is_file()]
    assert missing == []


def test_stability_map_page_code_prints_what_its_comment_says(capsys):
    page = (REPO / "docs" / "howto" / "stability-maps.md").read_text(encoding="utf-8")
    (block,) = _python_blocks(page)
    exec(compile(block, "stability-maps", "exec"), {})
    shown = re.search(r"print\(notes\)\s+# (.*)", block).group(1)
    assert capsys.readouterr().out.strip() == shown
