"""Find ``fmusim``, the FMI standard's reference importer (modelica/Reference-FMUs).

``fmusim`` imports FMI 1.0, 2.0 and 3.0 FMUs (co-simulation and Model Exchange) and runs
one FMU alone: start values (``--start-value NAME VALUE``, an array's elements separated
by spaces), inputs from a CSV (``--input-file``), outputs to a CSV (``--output-file``,
``%.16g``). The tests run delaycomp's FMI 3.0 FMUs in it (``tests/test_fmi3_tools.py``).

It is searched in the folder named by ``DELAYCOMP_FMUSIM`` (a folder holding
``bin/fmusim``), else in ``../shared/tools/fmusim`` beside the checkout; it is built from
Reference-FMUs v0.0.39 (the last release with the C ``fmusim``) in about a minute. It is
in no package registry, so a machine without it still checks what it computed:
``scripts/record_fmusim.py`` records its runs (inputs, start values, command line, output
CSV or log) into ``reference/fmusim/``, and the tests drive our master through the same
calls against those records; the tests that run fmusim itself run where it is found, are
skipped (saying so) where it is not, and fail where ``DELAYCOMP_FMUSIM`` names a folder
without it.
"""

from __future__ import annotations

import csv
import os
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from delaycomp.errors import DelaycompError

#: the environment variable that names a folder holding ``bin/fmusim``
ENV = "DELAYCOMP_FMUSIM"
#: the command line inside such a folder
CLI_SUBPATH = Path("bin") / "fmusim"
#: the folder searched when ``DELAYCOMP_FMUSIM`` is not set: beside the checkout
DEFAULT = Path(__file__).resolve().parents[2].parent / "shared" / "tools" / "fmusim"
BUILD_HINT = ("build it from modelica/Reference-FMUs v0.0.39, the last release with the C "
              "fmusim (that tag's build/build_cvode.py, build_libxml2.py, build_zlib.py, "
              "then build.py x86_64-linux; about a minute), and set "
              f"{ENV}=FOLDER (the folder holding {CLI_SUBPATH.as_posix()}; default "
              "<repository>/../shared/tools/fmusim)")


class FmusimNotInstalled(DelaycompError, RuntimeError):
    """fmusim was not found (one-line message with the build hint)."""


def locate() -> Path:
    """The ``fmusim`` executable from ``$DELAYCOMP_FMUSIM``, else from the default folder.

    Raises
    ------
    FmusimNotInstalled
        The folder holds no executable ``bin/fmusim``; the message names the folder, where
        it came from and how to build fmusim.
    """
    folder = os.environ.get(ENV)
    root = Path(folder).expanduser() if folder else DEFAULT
    cli = root / CLI_SUBPATH
    if not (cli.is_file() and os.access(cli, os.X_OK)):
        where = f"{ENV}={folder}" if folder else f"{root} ({ENV} is not set)"
        raise FmusimNotInstalled(f"fmusim not found: {where} holds no executable "
                           f"{CLI_SUBPATH.as_posix()}: {BUILD_HINT}")
    return cli.resolve()


def simulate(fmu: Path, options: Sequence[str], input_file: Path | None, output_file: Path,
             cli: Path | None = None, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """Run ``fmusim OPTIONS [--input-file IN] --output-file OUT FMU``.

    Parameters
    ----------
    fmu : Path
        The FMU (any FMI version fmusim reads).
    options : sequence of str
        fmusim's options, e.g. ``["--interface-type", "cs", "--stop-time", "3.0",
        "--start-value", "A", "0.0 1.0 -2.0 -3.0"]``.
    input_file, output_file : Path
        The input CSV (``time`` first, one column per input; none: no inputs) and the
        output CSV fmusim writes (``time`` and the outputs, ``%.16g``).
    cli : Path, optional
        The executable; default ``locate()``.
    timeout : float
        Seconds before the run is stopped (``subprocess.TimeoutExpired``).

    Returns
    -------
    subprocess.CompletedProcess
        With ``returncode`` (0 OK, 1 warning, 2 discard, 3 error, 4 fatal) and the text
        ``stdout`` and ``stderr`` (the FMU's log lines: ``[Error] fmi3DoStep ...``).
    """
    argv = [str(cli or locate()), *options]
    if input_file is not None:
        argv += ["--input-file", str(input_file)]
    argv += ["--output-file", str(output_file), str(fmu)]
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout)


def read_output(path: Path) -> tuple[list[str], np.ndarray]:
    r"""The header and the numbers (rows x columns, float) of an fmusim output CSV.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     out = Path(tmp) / "out.csv"
    ...     _ = out.write_text('"time","x"\n0,1\n0.01,0.9900498337491681\n')
    ...     header, data = read_output(out)
    >>> header, data.shape, float(data[1, 1])
    (['time', 'x'], (2, 2), 0.9900498337491681)
    """
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        return [], np.zeros((0, 0))
    data = np.array(rows[1:], dtype=float).reshape(len(rows) - 1, len(rows[0]))
    return rows[0], data
