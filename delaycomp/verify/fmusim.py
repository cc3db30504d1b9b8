"""Find ``fmusim``, the FMI standard's reference importer (modelica/Reference-FMUs).

``fmusim`` imports FMI 1.0, 2.0 and 3.0 FMUs (co-simulation and Model Exchange) and runs
one FMU alone: start values (``--start-value NAME VALUE``, an array's elements separated
by spaces), inputs from a CSV (``--input-file``), outputs to a CSV (``--output-file``,
``%.16g``). The tests run delaycomp's FMI 3.0 FMUs in it (``tests/test_fmi3_tools.py``).

It is searched in the folder named by ``DELAYCOMP_FMUSIM`` (a folder holding
``bin/fmusim``), else in ``../shared/tools/fmusim`` beside the checkout, where
``build.sh`` of that folder builds it from Reference-FMUs v0.0.39 (the last release with
the C ``fmusim``) offline in about a minute; ``.ci/run`` exports the variable.
"""

from __future__ import annotations

import os
from pathlib import Path

from delaycomp.errors import DelaycompError

#: the environment variable that names a folder holding ``bin/fmusim``
ENV = "DELAYCOMP_FMUSIM"
#: the command line inside such a folder
CLI_SUBPATH = Path("bin") / "fmusim"
#: the folder searched when ``DELAYCOMP_FMUSIM`` is not set: beside the checkout
DEFAULT = Path(__file__).resolve().parents[2].parent / "shared" / "tools" / "fmusim"
BUILD_HINT = ("build it from modelica/Reference-FMUs v0.0.39, the last release with the C "
              "fmusim (offline: `bash build.sh WORKDIR FOLDER` of the shared tools' fmusim "
              "folder, about a minute; online: that tag's build/build_cvode.py, "
              "build_libxml2.py, build_zlib.py, then build.py x86_64-linux), and set "
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
