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
    output = re.search(r"prints\n\n(?:<!--.*?-->\n\n)?```text\n(.*?)```", text, flags=re.S)
    shown = dict(line.split() for line in output.group(1).splitlines())
    assert printed.keys() == shown.keys() == {"compensated", "uncompensated"}
    # dead-beat: the compensated cart is at the origin to round-off (|x0| = 1 scale)
    assert abs(float(printed["compensated"])) < 1e-12
    assert abs(float(shown["compensated"])) < 1e-12
    # the uncompensated swing is an exact ZOH computation: the page's digits, to round-off
    assert abs(float(printed["uncompensated"]) - float(shown["uncompensated"])) < 1e-9
    exec(compile(blocks[1], "tutorial-2", "exec"), namespace)
    assert (tmp_path / "cart.png").stat().st_size > 0


def test_the_api_page_shows_every_api_name():
    """``::: delaycomp.api`` lists its members, in the order the page reads (most functions
    live in the package's private modules, re-exported): every name of ``__all__`` and
    every public function or class defined in ``delaycomp.api`` itself is there, but
    ``Result``, shown under Running with its module."""
    import inspect

    from delaycomp import api

    page = (REPO / "docs" / "reference" / "api.md").read_text(encoding="utf-8")
    listed = re.search(r"^::: delaycomp\.api\n    options:\n      members: \[(.*?)\]$", page,
                       flags=re.M)
    assert listed is not None
    members = [name.strip() for name in listed.group(1).split(",")]
    public = {name for name, value in vars(api).items() if not name.startswith("_")
              and (inspect.isfunction(value) or inspect.isclass(value))
              and value.__module__ == "delaycomp.api"}
    assert set(members) == (set(api.__all__) | public) - {"Result"}
    assert len(members) == len(set(members))


def test_every_page_in_the_nav_exists():
    nav = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    pages = re.findall(r"([\w/.-]+\.md)\s*$", nav, flags=re.M)
    assert len(pages) > 15
    missing = [p for p in pages if not (REPO / "docs" / p).is_file()]
    assert missing == []


README = REPO / "README.md"


def test_commands_page_states_the_grid_rule_of_r_and_tau_as_list_does():
    """The commands page's ``list`` bullet gives the allowed ranges of ``r`` and ``tau`` in
    the words ``delaycomp list`` prints (``delaycomp.paper.scenarios``; the Scenarios page
    is ``list`` itself, generated when the site is built)."""
    from delaycomp.paper import scenarios
    text = (REPO / "docs" / "reference" / "commands.md").read_text(encoding="utf-8")
    plain = " ".join(text.replace("`", "").split())
    sc = scenarios.get("example-3.6")
    assert sc.param("r").allowed == scenarios.ON_BASE_GRID
    assert f'is "{scenarios.ON_BASE_GRID}", as list says' in plain
    assert f'zero-order hold tau is "{scenarios.ZOH_TAU}"' in plain
    assert "<!-- delaycomp:scenarios -->" in (REPO / "docs" / "reference" / "scenarios.md"
                                              ).read_text(encoding="utf-8")


def test_readme_python_example_installs_what_it_imports():
    """The README's first command installs the extra its Python example needs (so the
    example runs after it; .ci/wheel-smoke runs it so), the extra exists and brings every
    third-party module the example imports beyond the core dependencies."""
    import ast
    import sys

    import tomllib

    text = README.read_text(encoding="utf-8")
    example = REPO / "docs" / "examples" / "own_plant.py"
    first = re.search(r"```sh\n(.*)\n```", text).group(1)  # the README's first command
    line = re.match(r"python3 -m venv \.venv && \.venv/bin/pip install '\.\[(\w+)\]' && ",
                    first)
    assert line, f"README's first command installs no extra: {first}"
    extra = line.group(1)
    assert "\n.venv/bin/python docs/examples/own_plant.py\n" in text  # how to run it
    assert f'pip install "$(ls dist/delaycomp-*.whl)[{extra}]"' in text  # the wheel form
    assert f"| `{extra}` | python-control |" in text                     # the extras table
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    extras = project["optional-dependencies"]
    assert extras[extra] == ["control>=0.10"]
    assert any(extra in spec for spec in extras["test"] if spec.startswith("delaycomp["))

    def names(specs):
        return {re.match(r"[A-Za-z0-9_.-]+", s).group(0).lower() for s in specs}

    installed = names(project["dependencies"]) | names(extras[extra]) | {"delaycomp"}
    imported = {(node.module if isinstance(node, ast.ImportFrom) else alias.name)
                .split(".")[0]
                for node in ast.walk(ast.parse(example.read_text(encoding="utf-8")))
                if isinstance(node, ast.Import | ast.ImportFrom)
                for alias in node.names}
    third_party = imported - set(sys.stdlib_module_names)
    assert "control" in third_party
    assert third_party <= installed, third_party - installed
    assert "control" not in names(project["dependencies"])


def test_readme_is_short_and_its_links_lead_somewhere():
    """The README is the front page: a few hundred lines at most (the rest lives on the
    documentation site), and every relative link and image in it names a file or folder of
    the repository (GitHub renders them; the site includes README sections through
    ``scripts/mkdocs_hooks.py``)."""
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 300
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    local = [t.split("#")[0] for t in targets if not re.match(r"[a-z]+://", t) and t[0] != "#"]
    assert len(local) > 20
    missing = [t for t in local if not (REPO / t).exists()]
    assert missing == []
    for section in ("The two commands", "Your controller as an FMU", "Your own plant",
                    "The masters it runs in", "Documentation", "Install and extras",
                    "Contributing"):
        assert f"\n## {section}\n" in text, section


def test_readme_extras_table_lists_every_extra():
    """Every optional dependency group of pyproject.toml has a row in the README's table,
    and each row names the distributions the extra brings."""
    import tomllib

    text = README.read_text(encoding="utf-8")
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")] if line.startswith("| `") else []
        for name in re.findall(r"`(\w+)`", cells[0]) if cells else ():
            rows[name] = cells[1].lower()
    extras = project["optional-dependencies"]
    assert set(extras) <= set(rows), set(extras) - set(rows)
    for name, specs in extras.items():
        for spec in specs:
            dist = re.match(r"[A-Za-z0-9_.-]+", spec).group(0).lower()
            if dist == "delaycomp":
                continue
            assert dist.split("-")[0].replace("py", "") in rows[name].replace("py", "") \
                or dist in rows[name], (name, dist, rows[name])


def test_site_commands_are_the_readmes():
    """The site's front page takes the two commands and the documentation command from the
    README when it is built (no second copy that could drift)."""
    index = (REPO / "docs" / "index.md").read_text(encoding="utf-8")
    assert "<!-- delaycomp:readme The two commands -->" in index
    assert "<!-- delaycomp:readme Documentation -->" in index
    assert "```sh" not in index
    hooks = _hooks()
    body = hooks.readme_section("The two commands", "index.md")
    first = re.search(r"```sh\n(.*)\n```", README.read_text(encoding="utf-8")).group(1)
    assert first in body
    # links into docs/ become relative to the page that includes them
    assert "](docs/" not in hooks.readme_section("Documentation", "howto/page.md")
    assert "](../tutorial.md)" in hooks.readme_section("Documentation", "howto/page.md")


def _hooks():
    import importlib.util
    spec = importlib.util.spec_from_file_location("hooks", REPO / "scripts" / "mkdocs_hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return hooks


def test_the_link_checker_finds_what_a_reader_would_stumble_on(tmp_path):
    """``mkdocs build`` (CI, strict) follows every link of the built site
    (``scripts/mkdocs_hooks.py``, ``on_post_build``); here on a site of four pages."""
    site = tmp_path / "site"
    (site / "howto").mkdir(parents=True)
    (site / "index.html").write_text(
        '<a href="howto/a.html#step">ok</a> <a href="howto/a.html#nowhere">anchor</a> '
        '<a href="howto/">folder</a> <img src="figures/gone.png"> '
        '<a href="https://example.org/x">other site</a> <a href="#top">here</a>'
        '<h1 id="top">t</h1>', encoding="utf-8")
    (site / "howto" / "a.html").write_text('<h2 id="step">s</h2><a href="../index.html">up</a>'
                                           '<a href="../../outside.html">out</a>',
                                           encoding="utf-8")
    (tmp_path / "outside.html").write_text("x", encoding="utf-8")
    (site / "404.html").write_text('<a href="/whatever/">root</a>', encoding="utf-8")
    problems = _hooks().check_links(site)
    assert problems == [
        "howto/a.html: ../../outside.html: outside the site",
        "index.html: howto/a.html#nowhere: no anchor #nowhere there",
        "index.html: howto/: a folder (a site opened from disk cannot follow it)",
        "index.html: figures/gone.png: no such file",
    ]
    mkdocs = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    assert "use_directory_urls: false" in mkdocs and "scripts/mkdocs_hooks.py" in mkdocs



#: a Sphinx cross-reference role (````x````): the API pages render the numpydoc
#: docstrings through mkdocstrings, which shows a role as raw text
ROLE = re.compile(r":(?:py:)?[a-z]+:`")


def test_docstrings_use_one_style_that_the_site_renders():
    """No Sphinx role anywhere in the Python sources (names are written as double-backtick
    code, ````delaycomp.api.run````); the built site is checked for them too
    (``scripts/mkdocs_hooks.py``)."""
    found = []
    for folder in ("delaycomp", "orchestrator", "fmus", "reference", "scripts", "bench",
                   "tests"):
        for path in sorted((REPO / folder).rglob("*.py")):
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if ROLE.search(line) and "ROLE = re.compile" not in line:
                    found.append(f"{path.relative_to(REPO)}:{number}: {line.strip()}")
    assert found == []
    hooks = _hooks()
    role = ":" + "func:`"  # spelled in two parts, so that this file holds no role
    assert hooks.raw_roles(f"<p>see {role}delaycomp.api.run`</p>") == [role]
    assert hooks.raw_roles("<p>see <code>delaycomp.api.run</code></p>") == []
