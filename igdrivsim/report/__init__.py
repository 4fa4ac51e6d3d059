"""The paper's outputs from evaluations: tables, figures, provenance, the results page and
the PDF's result macros (docs/ARCHITECTURE.md lists each module's job)."""
