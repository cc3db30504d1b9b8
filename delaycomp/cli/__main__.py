"""``python -m delaycomp.cli``: the same as the ``delaycomp`` command."""

from delaycomp.cli import entry

if __name__ == "__main__":
    entry()
