"""Model modules of the paper's examples, in the format of ``delaycomp.maths.model``.

Each is an ordinary model file, built into FMUs exactly like a user's ``--model FILE.py``.
"""

from pathlib import Path

HERE = Path(__file__).resolve().parent


def path(name: str) -> Path:
    """Path of the built-in model module ``name`` (e.g. ``"example_2_4"``)."""
    return HERE / f"{name}.py"
