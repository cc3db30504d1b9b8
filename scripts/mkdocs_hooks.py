"""MkDocs hooks: pages generated from the code, so they cannot drift from it.

``<!-- delaycomp:cli -->`` in a page becomes the ``--help`` of ``delaycomp`` and of every
subcommand (from ``delaycomp.cli._parser``, the parser the command runs);
``<!-- delaycomp:scenarios -->`` becomes the output of ``delaycomp list``;
``<!-- delaycomp:loop-keys -->`` the loop-file reader's key table
(``delaycomp.system.loopkeys.markdown``);
``<!-- delaycomp:include FILE.md -->`` becomes that file of the repository (the benchmark
reports the scripts in ``bench/`` write), without its title and with its links to
``docs/`` made relative to the page; ``<!-- delaycomp:readme SECTION -->`` becomes the
README's section of that title (its commands, so that the site and the README cannot give
different ones).

When the site is built, ``check_links`` follows every link and image of every page of
it (``on_post_build``): a link to a file that is not there, to an anchor the page does not
have, or to a folder (which a site opened from disk cannot follow) fails the build, as
does a Sphinx role left raw in a page (``raw_roles``).
"""

from __future__ import annotations

import contextlib
import io
import re
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

CLI_MARK = "<!-- delaycomp:cli -->"
SCENARIOS_MARK = "<!-- delaycomp:scenarios -->"
LOOP_KEYS_MARK = "<!-- delaycomp:loop-keys -->"
INCLUDE = re.compile(r"<!-- delaycomp:include ([\w./-]+\.md) -->")
README_SECTION = re.compile(r"<!-- delaycomp:readme ([^>]+?) -->")
REPO = Path(__file__).resolve().parent.parent


def _help(parser) -> str:
    return parser.format_help().rstrip()


def cli_reference() -> str:
    """Markdown with the help of ``delaycomp`` and of each subcommand."""
    import argparse

    from delaycomp.cli import _parser

    parser = _parser()
    parser.prog = "delaycomp"
    parts = ["## delaycomp", "", "```text", _help(parser), "```", ""]
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in action.choices.items():
        parts += [f"## delaycomp {name}", "", "```text", _help(sub), "```", ""]
    return "\n".join(parts)


def scenario_list() -> str:
    """``delaycomp list`` as a text block."""
    from delaycomp.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["list"])
    return "```text\n" + buf.getvalue().rstrip() + "\n```\n"


def loop_keys() -> str:
    """The tables of every loop-file key, from the reader's own table."""
    from delaycomp.system.loopfile import KEYS
    from delaycomp.system.loopkeys import markdown

    return markdown({key: spec.allowed for key, spec in KEYS.items()})


def _relative(text: str, page_path: str) -> str:
    """Links into ``docs/`` (as the repository's root files write them) made relative to
    the page at ``page_path``; links to other files of the repository are left alone."""
    up = "../" * page_path.count("/")
    return re.sub(r"\]\(docs/", "](" + up, text)


def readme_section(title: str, page_path: str) -> str:
    """The body of the README's ``## title`` section (without its heading)."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, flags=re.S | re.M)
    if match is None:
        raise ValueError(f"README.md has no section '## {title}'")
    return _relative(match.group(1).strip(), page_path) + "\n"


def include(name: str, page_path: str) -> str:
    """The repository's markdown file ``name`` as part of the page at ``page_path``
    (relative to ``docs/``): its ``# title`` dropped, links into ``docs/`` rewritten."""
    text = (REPO / name).read_text(encoding="utf-8")
    lines = text.splitlines()
    if lines and lines[0].startswith("# "):
        lines = lines[1:]
    return _relative("\n".join(lines), page_path).strip() + "\n"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if CLI_MARK in markdown:
        markdown = markdown.replace(CLI_MARK, cli_reference())
    if SCENARIOS_MARK in markdown:
        markdown = markdown.replace(SCENARIOS_MARK, scenario_list())
    if LOOP_KEYS_MARK in markdown:
        markdown = markdown.replace(LOOP_KEYS_MARK, loop_keys())
    markdown = README_SECTION.sub(
        lambda m: readme_section(m.group(1), page.file.src_uri), markdown)
    markdown = INCLUDE.sub(lambda m: include(m.group(1), page.file.src_uri), markdown)
    return markdown


class _Links(HTMLParser):
    """The links (``href``, ``src``) and the anchors (``id``, ``name``) of an HTML page."""

    def __init__(self):
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if value is None:
                continue
            if name in ("href", "src"):
                self.links.append(value)
            elif name in ("id", "name") and tag != "meta":
                self.ids.add(value)


def _parse(path: Path) -> _Links:
    parser = _Links()
    parser.feed(path.read_text(encoding="utf-8", errors="replace"))
    return parser


def check_links(site: Path) -> list[str]:
    """Every broken link of the built ``site``, one line each (``[]`` if none): a relative
    link or image to a file that is not there, to an anchor its page does not have, or to
    a folder. Links to other sites are not followed (no network); the 404 page, whose
    links are absolute by design, is left out."""
    site = Path(site).resolve()
    pages: dict[Path, _Links] = {}

    def page(path: Path) -> _Links:
        if path not in pages:
            pages[path] = _parse(path)
        return pages[path]

    problems = []
    for html in sorted(site.rglob("*.html")):
        if html.name == "404.html":
            continue
        for url in page(html).links:
            parts = urlsplit(url)
            if parts.scheme or parts.netloc or url.startswith("/"):
                continue  # another site, mailto:, data:, or the server's root
            where = f"{html.relative_to(site)}: {url}"
            target = (html.parent / unquote(parts.path)).resolve() if parts.path else html
            if parts.path.endswith("/") or target.is_dir():
                problems.append(f"{where}: a folder (a site opened from disk cannot follow it)")
            elif not target.is_file():
                problems.append(f"{where}: no such file")
            elif not target.is_relative_to(site):
                problems.append(f"{where}: outside the site")
            elif parts.fragment and target.suffix == ".html" \
                    and unquote(parts.fragment) not in page(target).ids:
                problems.append(f"{where}: no anchor #{parts.fragment} there")
    return problems


#: a Sphinx role left raw in a rendered page (the docstrings are numpydoc without roles)
RAW_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|exc|obj|const|ref):`")


def raw_roles(html: str) -> list[str]:
    """The Sphinx roles a rendered page shows as raw text."""
    return RAW_ROLE.findall(html)


def on_post_build(config) -> None:
    from mkdocs.exceptions import PluginError

    site = Path(config["site_dir"])
    problems = check_links(site)
    problems += [f"{page.relative_to(site)}: raw role {role} (write ``name``)"
                 for page in sorted(site.rglob("*.html"))
                 for role in raw_roles(page.read_text(encoding="utf-8", errors="replace"))]
    if problems:
        raise PluginError(f"{len(problems)} problems in the built site:\n"
                          + "\n".join(problems))
