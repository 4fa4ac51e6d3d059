"""Table I (LaTeX and Markdown) and the side-by-side comparison with the paper's numbers.

Inputs are the frames of :mod:`igdrivsim.evaluation.aggregate`: ``summary`` (mean and CI per
metric, setting, method) and ``tests`` (BC-RL vs BC per metric and setting). Layout follows the
paper's Table I: metrics are row groups holding a BC-RL row and a BC row, the six observation
settings are columns, and the better value of a significantly different pair is in bold. Two
reference rows (discretised expert replay, constant velocity) follow when they were evaluated;
they do not depend on the observation, so they span the six columns.
"""

from __future__ import annotations

import math

import pandas as pd

from igdrivsim.evaluation.aggregate import ALPHA, TEST_NAME
from igdrivsim.evaluation.schema import (
    BC,
    BC_RL,
    METHOD_LABELS,
    METRICS,
    PAPER_TABLE1,
    REFERENCE_SETTING,
    REFERENCES,
    SETTING_LABELS,
    SETTING_SHORT,
    SETTINGS,
)

MISSING = "--"


def _lookup(summary: pd.DataFrame, metric: str, setting: str, method: str) -> pd.Series | None:
    rows = summary[(summary.metric == metric) & (summary.setting == setting)
                   & (summary.method == method)]
    return None if rows.empty else rows.iloc[0]


def _better(tests: pd.DataFrame, metric: str, setting: str) -> str:
    if tests is None or tests.empty:
        return ""
    rows = tests[(tests.metric == metric) & (tests.setting == setting)]
    return "" if rows.empty else str(rows.iloc[0].better or "")


def _fmt(value: float) -> str:
    return MISSING if value is None or not math.isfinite(value) else f"{value:.2f}"


def _has_references(summary: pd.DataFrame) -> list[str]:
    return [m for m in REFERENCES
            if ((summary.method == m) & (summary.setting == REFERENCE_SETTING)).any()]


def table1_latex(summary: pd.DataFrame, tests: pd.DataFrame, caption_extra: str = "") -> str:
    """The ``table*`` float for the report (needs booktabs, colortbl and the colours
    ``bcrlcolor`` / ``bccolor`` defined by the report preamble)."""
    colours = {BC_RL: "bcrlcolor", BC: "bccolor"}
    lines = [
        r"\begin{table*}[t]",
        r"\centering",
        r"\caption{\textbf{BC-RL versus BC under six observation models.} Mean over seeds of "
        r"per-step (log divergence, overlap, offroad) and per-scenario (max log divergence, "
        r"overlap rate, offroad rate) metrics on the validation scenarios; lower is better. "
        r"Orange rows: BC-RL ($w_{BC}=1$, $w_{RL}=0.05$); blue rows: BC. Bold marks the "
        rf"better method where the difference is significant ({TEST_NAME}, "
        rf"$\alpha={ALPHA}$). {caption_extra}}}",
        r"\label{tab:results}",
        r"\resizebox{\textwidth}{!}{%",
        r"\begin{tabular}{l" + "c" * len(SETTINGS) + "}",
        r"\toprule",
        r"\textbf{Metric} & " + " & ".join(
            rf"\textbf{{{SETTING_LABELS[s][0]}}}" for s in SETTINGS) + r" \\",
        " & " + " & ".join(
            rf"\textbf{{{SETTING_LABELS[s][1]}}}" if SETTING_LABELS[s][1] else ""
            for s in SETTINGS) + r" \\",
    ]
    references = _has_references(summary)
    for metric in METRICS:
        lines.append(r"\midrule")
        for i, method in enumerate((BC_RL, BC)):
            cells = []
            for setting in SETTINGS:
                row = _lookup(summary, metric.key, setting, method)
                text = _fmt(None if row is None else float(row["mean"]))
                if _better(tests, metric.key, setting) == method:
                    text = rf"\textbf{{{text}}}"
                cells.append(rf"\cellcolor{{{colours[method]}}}{text}")
            lines.append(metric.label[i] + " & " + " & ".join(cells) + r" \\")
        for method in references:
            row = _lookup(summary, metric.key, REFERENCE_SETTING, method)
            value = _fmt(None if row is None else float(row["mean"]))
            lines.append(rf"\quad\textit{{{METHOD_LABELS[method].lower()}}} & "
                         rf"\multicolumn{{{len(SETTINGS)}}}{{c}}{{\textit{{{value}}}}} \\")
    lines += [r"\bottomrule", r"\end{tabular}%", "}", r"\end{table*}", ""]
    return "\n".join(lines)


def _ci_text(row: pd.Series | None) -> str:
    if row is None:
        return MISSING
    mean, low, high = float(row["mean"]), float(row["ci_low"]), float(row["ci_high"])
    if not math.isfinite(low):
        return _fmt(mean)
    return f"{mean:.2f} ± {(high - low) / 2:.2f}"


def safety_verdicts(tests: pd.DataFrame) -> dict[str, str]:
    """Per setting, a one-line answer to "is BC-RL safer than BC?" from the safety metrics
    (overlap %, overlap rate, offroad %, offroad rate) and their significance."""
    safety = ("overlap", "overlap_rate", "offroad", "offroad_rate")
    verdicts = {}
    for setting in SETTINGS:
        rows = tests[(tests.setting == setting) & tests.metric.isin(safety)] if len(tests) else []
        if len(rows) == 0:
            verdicts[setting] = "not evaluated"
            continue
        wins = int(((rows.better == BC_RL)).sum())
        losses = int(((rows.better == BC)).sum())
        lower = int((rows["diff"] < 0).sum())
        if wins and not losses:
            word = "yes"
        elif losses and not wins:
            word = "no (BC is safer)"
        elif wins and losses:
            word = "mixed"
        else:
            word = "no significant difference"
        verdicts[setting] = (f"{word}: BC-RL significantly better on {wins}/4 safety metrics, "
                             f"worse on {losses}/4, lower mean on {lower}/4")
    return verdicts


def table1_markdown(summary: pd.DataFrame, tests: pd.DataFrame, header: str = "") -> str:
    """Markdown version of Table I with 95% CI half-widths and the safety verdict per setting."""
    out = ["# Table I: BC-RL vs BC", ""]
    if header:
        out += [header, ""]
    out += ["Mean over seeds ± 95% CI half-width (t-distribution over seed means). **Bold**: the "
            f"better method where the difference is significant ({TEST_NAME}, alpha={ALPHA}). "
            "Lower is better for every metric.", ""]
    out.append("| metric | method | " + " | ".join(SETTING_SHORT[s] for s in SETTINGS) + " |")
    out.append("|---|---|" + "---|" * len(SETTINGS))
    references = _has_references(summary)
    for metric in METRICS:
        name = f"{' '.join(metric.label).replace(chr(92), '')}"
        for method in (BC_RL, BC):
            cells = []
            for setting in SETTINGS:
                text = _ci_text(_lookup(summary, metric.key, setting, method))
                if _better(tests, metric.key, setting) == method:
                    text = f"**{text}**"
                cells.append(text)
            out.append(f"| {name} | {METHOD_LABELS[method]} | " + " | ".join(cells) + " |")
        for method in references:
            text = _ci_text(_lookup(summary, metric.key, REFERENCE_SETTING, method))
            out.append(f"| {name} | *{METHOD_LABELS[method]}* | " + " | ".join(
                [f"*{text}*"] * len(SETTINGS)) + " |")
    out += ["", "## Is BC-RL safer than BC?", ""]
    for setting, verdict in safety_verdicts(tests).items():
        out.append(f"- **{SETTING_SHORT[setting]}**: {verdict}")
    return "\n".join(out) + "\n"


def vs_paper_markdown(summary: pd.DataFrame, tests: pd.DataFrame, header: str = "") -> str:
    """Our BC-RL / BC means next to the paper's published Table I, cell by cell.

    ``same direction`` says whether the sign of BC-RL minus BC agrees with the paper's.
    """
    out = ["# Our Table I next to the paper's", ""]
    if header:
        out += [header, ""]
    out += ["Paper: Grislain et al., Table I (WOMD validation, mean of 3 seeds). Absolute values "
            "are comparable only when both were computed on WOMD; on synthetic data compare the "
            "direction of the BC-RL minus BC difference.", ""]
    agree = total = 0
    for metric in METRICS:
        unit = f" ({metric.unit})"
        out += [f"## {' '.join(metric.label).replace(chr(92), '').replace(' (%)', '')}{unit}", "",
                "| setting | ours BC-RL | ours BC | ours diff | significant | paper BC-RL | "
                "paper BC | paper diff | same direction |",
                "|---|---|---|---|---|---|---|---|---|"]
        for setting in SETTINGS:
            ra = _lookup(summary, metric.key, setting, BC_RL)
            rb = _lookup(summary, metric.key, setting, BC)
            pa, pb = PAPER_TABLE1[metric.key][setting]
            a = float(ra["mean"]) if ra is not None else float("nan")
            b = float(rb["mean"]) if rb is not None else float("nan")
            diff, pdiff = a - b, pa - pb
            sig = ""
            if len(tests):
                t = tests[(tests.metric == metric.key) & (tests.setting == setting)]
                if not t.empty:
                    sig = f"{'yes' if t.iloc[0].significant else 'no'} (p={t.iloc[0].p_value:.3g})"
            same = MISSING
            if math.isfinite(diff):
                total += 1
                ok = (diff < 0) == (pdiff < 0) and diff != 0
                agree += ok
                same = "yes" if ok else "no"
            out.append(f"| {SETTING_SHORT[setting]} | {_fmt(a)} | {_fmt(b)} | "
                       f"{_fmt(diff) if math.isfinite(diff) else MISSING} | {sig or MISSING} | "
                       f"{pa:.2f} | {pb:.2f} | {pdiff:+.2f} | {same} |")
        out.append("")
    out.append(f"Direction of BC-RL minus BC agrees with the paper in {agree} of {total} "
               "evaluated cells.")
    return "\n".join(out) + "\n"
