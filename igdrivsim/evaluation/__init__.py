"""Closed-loop evaluation of trained policies and the reference actors (:mod:`.rollout`,
:mod:`.evaluate`, ``igdrivsim evaluate``), the metrics beyond Table I (:mod:`.registry`), the
tidy tables' names (:mod:`.schema`) and their statistics (:mod:`.aggregate`, :mod:`.paired`).
Tables and figures are :mod:`igdrivsim.report`.
"""
