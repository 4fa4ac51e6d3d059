"""Evaluation of trained policies, aggregation over seeds, Table I and Fig. 3.

- :mod:`.rollout`: closed-loop evaluation rollouts (policy, discretised expert, constant
  velocity) batched over scenarios and seeds -> tidy ``per_step.csv`` / ``per_scenario.csv``.
- :mod:`.registry`: the per-scenario metrics beyond Table I (progress, comfort, kinematic
  infeasibility, time to collision, PDM-style score), one entry each; see docs/metrics.md.
- :mod:`.aggregate`: means, 95% CIs over seeds, BC-RL vs BC significance tests.
- :mod:`.tables` / :mod:`.figures` / :mod:`.report`: Table I, the comparison with the paper,
  Fig. 3 and the report's provenance.
- :mod:`.pipeline`: the stages of ``scripts/reproduce.sh``.
"""
