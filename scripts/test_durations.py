"""Where the suite's time goes: a per-file table from pytest's JUnit XML.

    .venv/bin/python -m pytest -n auto --junitxml=out/junit.xml
    python scripts/test_durations.py out/junit.xml [--top 40] [--tests 20]

Prints, per test file (doctests per module), the tests run, failed and skipped, and the
seconds its tests took (setup, call and teardown: a session fixture's build is charged to
the first test that asks for it), largest first, with the share of the whole; then the
slowest single tests. Times are wall seconds inside the worker that ran them, so with
``-n N`` they add up to about N times the wall time.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict


def rows(path: str) -> list[tuple[str, str, float, str]]:
    """(file, test, seconds, outcome) for every test case of the report."""
    out = []
    for case in ET.parse(path).getroot().iter("testcase"):
        classname = case.get("classname", "")
        parts = classname.split(".")
        # tests.test_x.TestClass -> tests/test_x.py; delaycomp.mod -> delaycomp/mod.py
        mod = [p for p in parts if not p[:1].isupper()]
        file = "/".join(mod) + ".py"
        outcome = "passed"
        for tag in ("failure", "error", "skipped"):
            if case.find(tag) is not None:
                outcome = {"failure": "failed", "error": "failed"}.get(tag, tag)
        out.append((file, case.get("name", ""), float(case.get("time", 0.0)), outcome))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("junit")
    parser.add_argument("--top", type=int, default=60, help="files to list (default 60)")
    parser.add_argument("--tests", type=int, default=25, help="slowest tests to list")
    args = parser.parse_args(argv)
    data = rows(args.junit)
    total = sum(r[2] for r in data) or 1.0
    per: dict[str, list] = defaultdict(lambda: [0, 0, 0, 0.0])
    for file, _name, secs, outcome in data:
        entry = per[file]
        entry[0] += 1
        entry[1] += outcome == "failed"
        entry[2] += outcome == "skipped"
        entry[3] += secs
    print("| file | tests | failed | skipped | seconds | share |\n|---|---:|---:|---:|---:|---:|")
    for file, (n, failed, skipped, secs) in sorted(per.items(), key=lambda kv: -kv[1][3])[
            :args.top]:
        print(f"| {file} | {n} | {failed} | {skipped} | {secs:.1f} | {100 * secs / total:.1f} % |")
    print(f"| all ({len(per)} files) | {len(data)} | {sum(v[1] for v in per.values())} | "
          f"{sum(v[2] for v in per.values())} | {total:.1f} | 100 % |")
    print(f"\nslowest {args.tests} tests:")
    for file, name, secs, outcome in sorted(data, key=lambda r: -r[2])[:args.tests]:
        print(f"{secs:8.1f} s  {file}::{name}  ({outcome})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
