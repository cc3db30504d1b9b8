"""``python -m delaycomp``: the same as the ``delaycomp`` command."""

import sys

from delaycomp.cli import main

if __name__ == "__main__":
    sys.exit(main())
