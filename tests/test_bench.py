"""The benchmark script runs and writes its report (it measures nothing here: speed is
the benchmark's business, never a test's)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from .conftest import REPO

pytestmark = pytest.mark.fmu


def test_bench_quick_writes_report_and_plot(tmp_path):
    out, plot = tmp_path / "BENCHMARKS.md", tmp_path / "bench.png"
    proc = subprocess.run([sys.executable, str(REPO / "bench" / "run.py"), "--quick",
                           "--out", str(out), "--plot", str(plot)],
                          capture_output=True, text=True, timeout=600,
                          env={**os.environ,
                               "DELAYCOMP_CACHE_DIR": str(tmp_path / "cache")})
    assert proc.returncode == 0, proc.stderr
    text = out.read_text(encoding="utf-8")
    for heading in ("## Targets", "## 1. Wall time per simulated second",
                    "## 2. The master's own share", "## 3. Predictor cost per sample",
                    "## 4. Accuracy against cost", "## 5. Native C FMUs", "## 6. Start",
                    "## 7. Python FMUs: what instantiating one imports",
                    "## 8. A packed loop against OMSimulator", "## 9. Exact-grid steps"):
        assert heading in text
    # the continuous-input loop's observed order is printed and is first order
    order = [line for line in text.splitlines() if line.startswith("| example-2.4/default")
             and line.rstrip("| ").split("|")[-1].strip()]
    assert order and abs(float(order[-1].rstrip("| ").split("|")[-1]) - 1.0) < 0.1
    assert plot.stat().st_size > 10_000
