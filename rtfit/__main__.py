"""``python -m rtfit``: the ``rtfit`` command line."""

from rtfit.experiments.cli import main

if __name__ == "__main__":
    main()
