"""Closed-loop evaluation of trained policies and the reference actors, and its statistics.

- :mod:`.rollout`: closed-loop evaluation rollouts (policy, discretised expert, constant
  velocity) batched over scenarios and seeds -> tidy ``per_step.csv`` / ``per_scenario.csv``.
- :mod:`.evaluate`: one trained run (every seed) or the references -> those files on disk.
- :mod:`.registry`: the per-scenario metrics beyond Table I (progress, comfort, kinematic
  infeasibility, time to collision, PDM-style score), one entry each; see docs/metrics.md.
- :mod:`.schema`: the tidy tables' columns, settings, methods and metric labels.
- :mod:`.aggregate`: means, 95% CIs over seeds and scenarios, method comparisons with power.
- :mod:`.speed_walk`: the speed random walk of the discretised expert's labels (why sampled
  BC drifts along the road).
- :mod:`.commands`: ``igdrivsim evaluate``.

Tables, figures and the paper's outputs are :mod:`igdrivsim.report`; the whole reproduction is
:mod:`igdrivsim.pipeline`.
"""
