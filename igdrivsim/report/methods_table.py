"""Table II: every learned method against BC (Markdown and LaTeX), written when the evaluations
hold methods beyond BC and BC-RL; Holm runs over the table's cells (:func:`compare_all`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from igdrivsim.evaluation.aggregate import ALPHA, POWER, TEST_NAME, compare_methods
from igdrivsim.evaluation.schema import METRICS, REFERENCE_SETTING
from igdrivsim.names import (
    BC,
    BC_RL,
    LEARNED,
    METHOD_COLOURS,
    METHOD_LABELS,
    REFERENCES,
    setting_short,
)
from igdrivsim.report import tables as tab

PAPER_METHODS: tuple[str, ...] = (BC, BC_RL)


def learned_methods(frame: pd.DataFrame) -> list[str]:
    """The learned methods in ``frame``: BC, BC-RL, the registry's order, the rest."""
    present = set(frame["method"].astype(str)) - set(REFERENCES) if len(frame) else set()
    first = [m for m in PAPER_METHODS if m in present]
    registered = [m for m in LEARNED if m in present and m not in PAPER_METHODS]
    return first + registered + sorted(present - set(first) - set(registered))


def extended_methods(frame: pd.DataFrame) -> list[str]:
    """The learned methods in ``frame`` beyond the paper's BC and BC-RL (Table II order)."""
    return [m for m in learned_methods(frame) if m not in PAPER_METHODS]


def method_label(name: str) -> str:
    """A method's label: the registry's, a reference's, else the name itself."""
    return METHOD_LABELS.get(name, name)


def method_colours(methods: Sequence[str]) -> dict[str, str]:
    """Each method's registry colour, else a matplotlib cycle colour from ``C2``."""
    spare = [m for m in methods if m not in METHOD_COLOURS]
    return {m: METHOD_COLOURS.get(m) or f"C{2 + spare.index(m) % 8}" for m in methods}


def compare_all(per_scenario: pd.DataFrame) -> pd.DataFrame:
    """Every learned method but BC against it, Holm over Table II's cells."""
    return compare_methods(per_scenario, methods=[m for m in learned_methods(per_scenario)
                                                  if m != BC])


def _test(tests: pd.DataFrame, method: str, metric: str, setting: str) -> pd.Series | None:
    """``method`` against BC in a cell (None for BC itself, or without a difference)."""
    rows = tests[(tests.method == method) & (tests.metric == metric) & (tests.setting == setting)]
    if method == BC or rows.empty or not math.isfinite(float(rows.iloc[0]["diff"])):
        return None
    return rows.iloc[0]


def _ranges(tests: pd.DataFrame, column: str) -> str:
    """``lo–hi unit`` per metric unit over the cells with a finite ``column``."""
    parts = []
    for unit in dict.fromkeys(m.unit for m in METRICS):
        keys = [m.key for m in METRICS if m.unit == unit]
        values = tests.loc[tests.metric.isin(keys), column].to_numpy(float) if len(tests) else []
        values = [v for v in values if math.isfinite(v)]
        if values:
            parts.append(f"{min(values):.2f}–{max(values):.2f} {unit}")
    return ", ".join(parts) or tab.MISSING


def methods_caption(tests: pd.DataFrame) -> str:
    """The Holm and MDE sentence of Table II (plain text; LaTeX callers escape it)."""
    n = int(np.isfinite(tests.p_value.to_numpy(float)).sum()) if len(tests) else 0
    k = int(tests.significant.sum()) if len(tests) else 0
    return (f"Holm correction over the table's {n} comparison cells ({k} significant). "
            f"Minimum detectable effect ({POWER:.0%} power) at alpha={ALPHA}: "
            f"{_ranges(tests, 'mde')}; "
            f"at the strictest Holm level alpha/{n}: {_ranges(tests, 'mde_holm')}.")


def table2_markdown(summary: pd.DataFrame, tests: pd.DataFrame, header: str = "") -> str:
    """Markdown Table II from ``summary`` and ``tests`` (:func:`compare_all`)."""
    methods = learned_methods(summary)
    cols = tab.present_settings(summary[summary.method.isin(methods)])
    out = tab.heading("# Table II: learned methods vs BC", header)
    out += ["Mean over seeds ± 95% CI half-width (t-distribution over seed means); lower is "
            "better for every metric. Non-BC cells add Δ, the method minus BC, with its 95% "
            f"bootstrap interval ({TEST_NAME}); **bold**: significant after Holm "
            f"(alpha={ALPHA}). `{tab.MISSING}`: not evaluated in that setting.", "",
            *tab.md_head("metric", "method", *map(setting_short, cols))]
    for metric in METRICS:
        name = tab._metric_name(metric) + f" ({metric.unit})"
        for method in methods:
            cells = []
            for setting in cols:
                text = tab._ci_text(tab._lookup(summary, metric.key, setting, method))
                if (row := _test(tests, method, metric.key, setting)) is not None:
                    text = f"{text} (Δ {tab._diff_text(row)})"
                    text = tab.md_bold(text) if bool(row.significant) else text
                cells.append(text)
            out.append(tab.md_row(name, method_label(method), *cells))
        out += tab._reference_rows(summary, metric, name, len(cols))
    out += ["", methods_caption(tests)]
    return "\n".join(out) + "\n"


def table2_latex(summary: pd.DataFrame, tests: pd.DataFrame, caption_extra: str = "") -> str:
    """Table II as a ``table*`` float (label ``tab:methods``)."""
    methods = learned_methods(summary)
    cols = tab.present_settings(summary[summary.method.isin(methods)])
    holm = tab._tex(methods_caption(tests)).replace("alpha", r"$\alpha$").replace("–", "--")
    caption = (
        r"\caption{\textbf{Learned methods versus BC.} Mean over seeds $\pm$ 95\% CI "
        r"half-width on the validation scenarios; lower is better. Under each method, "
        r"$\Delta$: its difference from BC with the 95\% interval of a "
        rf"{tab._tex(TEST_NAME)}; bold: significant ($\alpha={ALPHA}$). "
        rf"{holm} "
        rf"{tab.MISSING}: not evaluated. {caption_extra}}}")
    lines = tab.setting_header(cols, r"\textbf{Metric} &")
    for metric in METRICS:
        lines.append(r"\midrule")
        first = f"{tab._metric_name(metric)} ({tab._tex(metric.unit)})"
        for method in methods:
            means, diffs = [], []
            for setting in cols:
                text = tab._ci_text(tab._lookup(summary, metric.key, setting, method))
                text = tab._tex_number(text).replace("±", r"$\pm$")
                row = _test(tests, method, metric.key, setting)
                diff = "" if row is None else tab._tex_number(tab._diff_text(row))
                if row is not None and bool(row.significant):
                    text, diff = tab.tex_bold(text), tab.tex_bold(diff)
                means.append(text)
                diffs.append(diff)
            lines.append(tab.tex_row(first, tab._tex(method_label(method)), *means))
            first = ""
            if method != BC:
                lines.append(tab.tex_row("", r"\quad\footnotesize $\Delta$ vs BC",
                                     *[rf"\footnotesize {d}" if d else "" for d in diffs]))
        for method in tab._has_references(summary):
            value = tab._fmt_mean(tab._lookup(summary, metric.key, REFERENCE_SETTING, method))
            lines.append(rf"{first} & \textit{{{tab._tex(method_label(method)).lower()}}} & "
                         + tab.tex_across(value, len(cols)))
            first = ""
    return tab.latex_float(caption, "tab:methods", "ll" + "c" * len(cols), lines)
