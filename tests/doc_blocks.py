"""Run the code blocks of a documentation page and compare what they print with the page.

A page's fenced blocks, in order, each one of:

- ``python``: executed, the page's blocks sharing one namespace, in a work folder that
  holds the repository's ``docs/examples`` (paths on the pages are from the checkout's
  root), as ``myloop.toml``, ``docs/examples/myloop.toml`` (the pages' "your loop"),
  and as ``.venv`` the running interpreter's environment (the README's
  ``.venv/bin/delaycomp``);
- ``sh`` / ``bash``: run by bash (``set -e``) in the same folder, with the ``delaycomp``
  and ``python`` of the running interpreter first on ``PATH`` (and OMSimulator's
  ``bin/`` where ``DELAYCOMP_OMSIMULATOR`` names it);
- ``text`` whose lines start with ``$ ``: each such command is run as above, and the lines
  under it are what it prints (a refusal too: its exit status is not checked, its words
  are);
- ``toml``: parsed; ``c``: compiled with ``cc -std=c99 -Wall -Werror -fsyntax-only``;
- ``text`` otherwise: a display (an equation, a file's shape), not code.

A marker on the line before the block changes that: ``<!-- doc-test: output -->`` makes a
``text`` block the output of the block before it (compared); ``<!-- doc-test: file NAME
-->`` writes the block into ``NAME`` in the work folder (for the blocks after it);
``<!-- doc-test: skip REASON -->`` leaves it out, and a reason is required;
``<!-- doc-test: c-declarations HEADER -->`` compiles a ``c`` block's prototypes after
``#include "HEADER"`` (a header an earlier block wrote: a prototype that differs from
the header's is an error; ``typedef struct`` sketches are left out), and
``<!-- doc-test: c-statements HEADER -->`` compiles a fragment of statements in a function
after it, with ``double y[PREFIX_NY], u[PREFIX_NU]`` and the board's
``receive_measurement(double *)``, ``send_command(double)`` and ``fault(int)`` declared. ``--8<--
"PATH"`` lines (the site's snippet includes) are replaced by the file.

Printed output is compared line by line: each line the page shows must appear, in order,
among the lines printed (notes between them are allowed). Text must be equal; numbers
agree to ``1e-9 (1 + |shown|)`` plus half a unit of the last digit shown (the pages show
``%g`` digits of exact computations whose last bits follow the machine's BLAS kernel);
durations (``in 0.39 s``) are not compared.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import shutil
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MARK = re.compile(r"<!--\s*doc-test:\s*([\w-]+)\s*(.*?)\s*-->")
FENCE = re.compile(r"^([ \t]*)```(\w*)[^\n]*\n(.*?)^\1```[ \t]*$", re.S | re.M)
SNIPPET = re.compile(r'^--8<-- "([^"]+)"$', re.M)
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
DURATION = re.compile(r"\bin (?:[0-9.]+) s\b")


@dataclass
class Block:
    page: str
    line: int
    lang: str
    body: str
    mark: str = ""
    arg: str = ""

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


def blocks(page: Path) -> list[Block]:
    """The fenced blocks of ``page`` with their markers, snippet includes resolved."""
    text = page.read_text(encoding="utf-8")
    out = []
    for m in FENCE.finditer(text):
        before = text[:m.start()].rstrip().splitlines()
        mark = MARK.fullmatch(before[-1].strip()) if before else None
        body = textwrap.dedent(m.group(3))  # a block in a list item is indented
        body = SNIPPET.sub(lambda s: (REPO / s.group(1)).read_text(encoding="utf-8"), body)
        name = str(page.relative_to(REPO)) if page.is_relative_to(REPO) else page.name
        out.append(Block(name, text[:m.start()].count("\n") + 1,
                         m.group(2) or "text", body, *(mark.groups() if mark else ("", ""))))
    return out


def _shown_tolerance(token: str) -> float:
    """Half a unit of the last digit ``token`` shows (``0.0125201`` -> 5e-8)."""
    mantissa, _, exp = token.lower().partition("e")
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    return 0.5 * 10.0 ** (int(exp or 0) - decimals)


def same_line(shown: str, printed: str) -> bool:
    """``printed`` says what ``shown`` says (module docstring)."""
    shown, printed = DURATION.sub("in * s", shown), DURATION.sub("in * s", printed)
    a, b = NUMBER.split(shown), NUMBER.split(printed)
    if a != b:
        return False
    for s, p in zip(NUMBER.findall(shown), NUMBER.findall(printed)):
        x, y = float(s), float(p)
        if not (math.isfinite(x) and math.isfinite(y)):
            if s != p:
                return False
        elif abs(x - y) > 1e-9 * (1 + abs(x)) + _shown_tolerance(s):
            return False
    return True


def check_output(shown: str, printed: str, where: str) -> None:
    """Each line of ``shown`` appears, in order, among the lines of ``printed``."""
    lines = [line.rstrip() for line in printed.splitlines()]
    at = 0
    for want in (line.rstrip() for line in shown.strip().splitlines()):
        while at < len(lines) and not same_line(want, lines[at]):
            at += 1
        if at == len(lines):
            raise AssertionError(f"{where}: the page shows\n  {want}\nwhich was not printed "
                                 f"(in order); printed:\n" + printed)
        at += 1


def environment() -> dict:
    env = dict(os.environ)
    bins = [str(Path(sys.executable).parent)]
    if env.get("DELAYCOMP_OMSIMULATOR"):
        bins.append(str(Path(env["DELAYCOMP_OMSIMULATOR"]) / "bin"))
    env["PATH"] = os.pathsep.join([*bins, env.get("PATH", "")])
    return env


def shell(script: str, cwd: Path, where: str, timeout: float = 600,
          check: bool = True) -> str:
    """Run ``script`` with bash -e; its standard output and error, merged (``check``: a
    non-zero exit status fails)."""
    done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", script], cwd=cwd,
                          env=environment(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=timeout)
    if check and done.returncode != 0:
        raise AssertionError(f"{where}: exit status {done.returncode}\n{script}\n"
                             f"{done.stdout}")
    return done.stdout


def run_page(page: Path, work: Path) -> dict:
    """Run every block of ``page`` in ``work`` (module docstring); return a summary:
    the blocks run and skipped, by language."""
    shutil.copytree(REPO / "docs" / "examples", work / "docs" / "examples",
                    dirs_exist_ok=True)
    shutil.copy(REPO / "docs" / "examples" / "myloop.toml", work / "myloop.toml")
    if not (work / ".venv").exists():  # the README's commands: .venv/bin/delaycomp
        (work / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    namespace: dict = {"__name__": "__doc_page__"}
    printed = None
    summary: dict = {"run": [], "skipped": [], "outputs": 0}
    old = Path.cwd()
    os.chdir(work)
    try:
        for block in blocks(page):
            if block.mark == "skip":
                assert block.arg, f"{block.where}: a skipped block needs a reason"
                summary["skipped"].append((block.where, block.arg))
                continue
            if block.mark == "output":
                assert printed is not None, f"{block.where}: no block before it printed"
                check_output(block.body, printed, block.where)
                summary["outputs"] += 1
                continue
            if block.mark in ("c-declarations", "c-statements"):
                _compile_c(block, work)
                summary["run"].append((block.where, block.lang))
                continue
            if block.mark == "file":
                (work / block.arg).write_text(block.body, encoding="utf-8")
            elif block.mark:
                raise AssertionError(f"{block.where}: unknown marker {block.mark!r}")
            lang = block.lang
            if lang == "python":
                buf = io.StringIO()
                with contextlib.redirect_stdout(buf):
                    exec(compile(block.body, block.where, "exec"), namespace)
                printed = buf.getvalue()
            elif lang in ("sh", "bash"):
                printed = shell(block.body, work, block.where)
            elif lang == "text" and block.body.startswith("$ "):
                printed = ""
                for command, shown in _sessions(block.body):
                    out = shell(command, work, block.where, check=False)
                    check_output(shown, out, block.where)
                    summary["outputs"] += 1
                    printed += out
            elif lang == "toml":
                import tomllib

                tomllib.loads(block.body)
            elif lang == "c":
                source = work / "block.c"
                source.write_text(block.body, encoding="utf-8")
                shell(f"cc -std=c99 -Wall -Werror -fsyntax-only {source.name}", work,
                      block.where)
            elif lang == "text":
                continue  # a display
            else:
                raise AssertionError(f"{block.where}: no rule to run a {lang} block")
            summary["run"].append((block.where, lang))
    finally:
        os.chdir(old)
    return summary


def _compile_c(block: Block, work: Path) -> None:
    """A ``c`` block against a header (the markers ``c-declarations``, ``c-statements``)."""
    header = work / block.arg
    assert header.is_file(), f"{block.where}: {block.arg} was not written by the page"
    prefix = header.stem
    if block.mark == "c-declarations":
        body = "\n".join(line for line in block.body.splitlines()
                         if not line.startswith("typedef struct"))
    else:
        body = (f"void receive_measurement(double *y);\nvoid send_command(double u);\n"
                f"void fault(int rc);\nvoid firmware(void) {{\n"
                f"    double y[{prefix}_NY], u[{prefix}_NU];\n{block.body}}}\n")
    source = work / "block.c"
    source.write_text(f'#include "{block.arg}"\n{body}\n', encoding="utf-8")
    shell(f"cc -std=c99 -Wall -Werror -fsyntax-only {source.name}", work, block.where)


def _sessions(body: str):
    """``$ command`` lines of a text block, each with the lines shown under it."""
    command, shown = None, []
    for line in body.splitlines():
        if line.startswith("$ "):
            if command is not None:
                yield command, "\n".join(shown)
            command, shown = line[2:], []
        else:
            shown.append(line)
    if command is not None:
        yield command, "\n".join(shown)
