"""The paper's outputs from evaluations: tables (markdown and LaTeX), figures, provenance.

- :mod:`.build`: every table and figure of one report from evaluation folders.
- :mod:`.tables`: Table I and the comparison with the paper; :mod:`.methods_table`: Table II.
- :mod:`.figures`: Fig. 3, Fig. 6 and the learning curves.
- :mod:`.real_logs`: the runs and references on real scenarios.
- :mod:`.results_doc` / :mod:`.results_tex`: the results page, the README block, the PDF's
  result macros, all written from the tables.
- :mod:`.provenance`: which command wrote each published file.
- :mod:`.commands`: ``igdrivsim report``.
"""
