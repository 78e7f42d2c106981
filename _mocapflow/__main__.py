"""``python -m mocapflow``: the command-line interface."""

import sys

from mocapflow.framework.cli import main

if __name__ == "__main__":
    sys.exit(main())
