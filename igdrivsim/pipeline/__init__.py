"""The whole reproduction (``scripts/reproduce.sh``, ``python -m igdrivsim.pipeline``); its
modules: docs/ARCHITECTURE.md."""
