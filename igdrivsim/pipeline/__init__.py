"""The whole reproduction (``scripts/reproduce.sh``, ``python -m igdrivsim.pipeline``).

- :mod:`.profiles`: the profiles' sizes (data, seeds, maze study).
- :mod:`.planning`: the machine, the grid split into parts, the wall-time estimate.
- :mod:`.runner`: resumable, logged stages.
- :mod:`.stages`: the stages in order, and publishing the report with its provenance.
- :mod:`.cli`: the command line.
"""
