"""The batch benchmark script runs and writes its report (it measures nothing here: speed
is the benchmark's business, never a test's)."""

from __future__ import annotations

import os
import subprocess
import sys

from .conftest import REPO


def test_bench_batch_quick_writes_report(tmp_path):
    out = tmp_path / "BENCHMARKS-batch.md"
    proc = subprocess.run([sys.executable, str(REPO / "bench" / "batch.py"), "--quick",
                           "--out", str(out)], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "DELAYCOMP_CACHE_DIR": str(tmp_path / "cache")})
    assert proc.returncode == 0, proc.stderr
    text = out.read_text(encoding="utf-8")
    rows = [line for line in text.splitlines() if line.startswith("| Example")
            or line.startswith("| Proposition")]
    assert len(rows) == 3
    # the batch results agree with the per-point engine on the sampled points (the bound
    # of tests/test_batch.py for model loops)
    assert all(float(row.rstrip("| ").split("|")[-1]) <= 1e-9 for row in rows)
    assert "Example 3.6 map of 10000 points" in text
