"""MkDocs hooks: pages generated from the code, so they cannot drift from it.

``<!-- delaycomp:cli -->`` in a page becomes the ``--help`` of ``delaycomp`` and of every
subcommand (from :func:`delaycomp.cli._parser`, the parser the command runs);
``<!-- delaycomp:scenarios -->`` becomes the output of ``delaycomp list``.
"""

from __future__ import annotations

import contextlib
import io

CLI_MARK = "<!-- delaycomp:cli -->"
SCENARIOS_MARK = "<!-- delaycomp:scenarios -->"


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


def on_page_markdown(markdown: str, page, config, files) -> str:
    if CLI_MARK in markdown:
        markdown = markdown.replace(CLI_MARK, cli_reference())
    if SCENARIOS_MARK in markdown:
        markdown = markdown.replace(SCENARIOS_MARK, scenario_list())
    return markdown
