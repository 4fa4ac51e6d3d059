"""``python -m igdrivsim.pipeline``: what ``scripts/reproduce.sh`` runs."""

import sys

from igdrivsim.pipeline.cli import main

if __name__ == "__main__":
    sys.exit(main())
