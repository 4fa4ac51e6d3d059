"""Synthetic WOMD-format scenarios: the embedded default data set (see ``generator.py``)."""
