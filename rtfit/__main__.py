"""``python -m rtfit``: the ``rtfit`` command line."""

import sys

from rtfit.experiments.cli import main

if __name__ == "__main__":
    sys.exit(main())
