"""Every code block of the tutorial and the how-to guides runs, and prints what the page
shows (issue 27, item 2; the rules are in ``tests/doc_blocks.py``)."""

from __future__ import annotations

import pytest

from .doc_blocks import REPO, blocks, check_output, run_page, same_line

PAGES = [REPO / "docs" / "tutorial.md", *sorted((REPO / "docs" / "howto").glob("*.md"))]


@pytest.mark.fmu
@pytest.mark.parametrize("page", PAGES, ids=[p.stem for p in PAGES])
def test_the_pages_code_runs_and_prints_what_it_shows(page, tmp_path, monkeypatch, request):
    if page.stem == "omsimulator":
        request.getfixturevalue("oms")  # skipped with its hint where it is not installed
    # the platforms beside linux64 are built and tested by tests/test_platforms.py; here
    # they would only cost time
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "")
    summary = run_page(page, tmp_path)
    code = [b for b in blocks(page) if b.lang not in ("text",) or b.body.startswith("$ ")]
    # nothing is left out without a reason, and most of a page's code runs
    assert len(summary["run"]) + len(summary["skipped"]) >= len(code)
    assert len(summary["skipped"]) <= len(code) // 2, summary["skipped"]


def test_every_page_with_code_has_a_block_that_runs():
    for page in PAGES:
        code = [b for b in blocks(page) if b.lang in ("python", "sh", "bash", "toml", "c")]
        runs = [b for b in code if b.mark != "skip"]
        assert not code or runs, page


def test_output_comparison_rules():
    assert same_line("cart: 201 rows to t = 10 in 0.39 s; final x = 1.61959e-32",
                     "cart: 201 rows to t = 10 in 12.5 s; final x = -3.1e-32")
    assert same_line("final plant.x = 0.0125201", "final plant.x = 0.01252014")
    assert not same_line("final plant.x = 0.0125201", "final plant.x = 0.0125211")
    assert not same_line("cart: 201 rows", "cart: 202 rows")
    assert not same_line("compensated 1", "uncompensated 1")
    check_output("a 1\nc 3", "a 1\nb 2\nc 3.0000000001\n", "here")
    with pytest.raises(AssertionError, match="was not printed"):
        check_output("c 3\na 1", "a 1\nb 2\nc 3\n", "here")


def test_a_page_that_drifted_fails(tmp_path):
    """The runner catches what a page can get wrong: a printed value, a command that
    fails, a prototype the generated header does not declare, a skip without a reason."""
    cases = {
        "value": '```python\nprint("x", 1 + 1)\n```\n\n<!-- doc-test: output -->\n\n'
                 '```text\nx 3\n```\n',
        "command": "```sh\ndelaycomp run no-such-scenario\n```\n",
        "prototype": '```sh\ndelaycomp export-c myloop.toml --prefix ctl --out fw\n```\n\n'
                     '<!-- doc-test: c-declarations fw/ctl.h -->\n\n'
                     '```c\nint ctl_sample(ctl_state *s, double t, double *y);\n```\n',
        "reason": "<!-- doc-test: skip -->\n\n```sh\nfalse\n```\n",
    }
    for name, text in cases.items():
        page = tmp_path / f"{name}.md"
        page.write_text(text, encoding="utf-8")
        work = tmp_path / name
        work.mkdir()
        with pytest.raises(AssertionError):
            run_page(page, work)
    # and the same pages, right, pass
    page = tmp_path / "right.md"
    page.write_text(cases["value"].replace("x 3", "x 2") + cases["prototype"].replace(
        "double *y", "const double *y"), encoding="utf-8")
    (tmp_path / "right").mkdir()
    assert run_page(page, tmp_path / "right")["outputs"] == 1


@pytest.mark.fmu
def test_the_readmes_path_runs_as_a_new_user_would_take_it(tmp_path, monkeypatch):
    """The README's code (issue 27: README -> first command -> own loop file -> own
    controller FMU): the loop file it shows is ``docs/examples/myloop.toml``, and every
    command after the set-up runs on it (build, export-c, run --compare, critical-delay,
    sweep, ssp, the Python example). The first command runs in ``.ci/wheel-smoke``."""
    monkeypatch.setenv("DELAYCOMP_PLATFORMS", "")
    readme = REPO / "README.md"
    toml = next(b for b in blocks(readme) if b.lang == "toml")
    assert toml.mark == "file" and toml.arg == "myloop.toml"
    assert toml.body == (REPO / "docs" / "examples" / "myloop.toml").read_text(encoding="utf-8")
    summary = run_page(readme, tmp_path)
    assert [w for w, _ in summary["skipped"]] == [
        b.where for b in blocks(readme) if b.mark == "skip"]
    assert len(summary["skipped"]) == 3
    assert (tmp_path / "fmus" / "myloop_controller.fmu").is_file()
    assert (tmp_path / "firmware" / "ctl.c").is_file()
    assert (tmp_path / "both.png").is_file() and (tmp_path / "own_plant.png").is_file()
