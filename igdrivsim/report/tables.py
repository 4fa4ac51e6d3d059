"""Table I (LaTeX and Markdown) with its effects, power and safety verdicts, the comparison with
the paper's numbers and the supplementary metrics, from :mod:`igdrivsim.evaluation.aggregate`'s
``summary`` and ``tests``; the Markdown and LaTeX writers the other tables share."""

from __future__ import annotations

import math
import re

import pandas as pd

from igdrivsim.evaluation.aggregate import ALPHA, POWER, TEST_NAME
from igdrivsim.evaluation.schema import METRICS, PAPER_TABLE1, REFERENCE_SETTING, table_settings
from igdrivsim.names import (
    BC,
    BC_RL,
    CONSTANT_VELOCITY,
    METHOD_LABELS,
    REFERENCES,
    SETTINGS,
    setting_labels,
    setting_short,
)

MISSING = "--"
# the width of the prose lines the report writes into the README
WIDTH = 96
# a markdown word: a code span, link or duration whole (they hold spaces), else a run of non-space
_WORD = re.compile(r"(?:\d+ h \d+ min|`[^`\n]*`|\[[^\]\n]*\]\([^)\s]*\)|\S)+")


def wrap(text: str, width: int = WIDTH, indent: str = "") -> list[str]:
    """``text`` as lines of at most ``width`` characters, continuation lines prefixed by
    ``indent``; a code span or a link is never split (a longer one stands on its own line)."""
    lines, line = [], ""
    for word in _WORD.findall(text):
        if line.strip() and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = indent + word
        else:
            line = f"{line} {word}" if line.strip() else line + word
    return lines + [line] if line else lines


def heading(title: str, header: str = "") -> list[str]:
    """A markdown page's first lines: its title, then ``header`` (the run's scope) if any."""
    return [title, "", *([header, ""] if header else [])]


def md_bold(text: str) -> str:
    return f"**{text}**"


def tex_bold(text: str) -> str:
    return rf"\textbf{{{text}}}"


def md_row(*cells: str) -> str:
    return "| " + " | ".join(cells) + " |"


def tex_row(*cells: str) -> str:
    return " & ".join(cells) + r" \\"


def md_head(*cells: str) -> list[str]:
    """A Markdown table's header row and rule."""
    return [md_row(*cells), "|" + "---|" * len(cells)]


def present_settings(frame: pd.DataFrame) -> list[str]:
    """The settings ``frame`` holds, in Table I's order."""
    present = set(frame.setting.astype(str))
    return [s for s in table_settings(frame) if s in present]


def _lookup(summary: pd.DataFrame, metric: str, setting: str, method: str) -> pd.Series | None:
    rows = summary[(summary.metric == metric) & (summary.setting == setting)
                   & (summary.method == method)]
    return None if rows.empty else rows.iloc[0]


def _cells(tests: pd.DataFrame | None) -> pd.DataFrame:
    """The rows of ``tests`` comparing BC-RL with BC (all rows if unlabelled)."""
    if tests is None or tests.empty:
        return pd.DataFrame(columns=["metric", "setting"])
    return tests[tests.method == BC_RL] if "method" in tests.columns else tests


def _test_row(tests: pd.DataFrame | None, metric: str, setting: str) -> pd.Series | None:
    cells = _cells(tests)
    rows = cells[(cells.metric == metric) & (cells.setting == setting)]
    return None if rows.empty else rows.iloc[0]


def _fmt(value: float | None, digits: int = 2) -> str:
    return MISSING if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _fmt_mean(row: pd.Series | None) -> str:
    return _fmt(math.nan if row is None else float(row["mean"]))


def cell_mean(summary: pd.DataFrame, metric: str, setting: str, method: str) -> float:
    """A ``summary.csv`` cell's mean (NaN when absent)."""
    row = _lookup(summary, metric, setting, method)
    return math.nan if row is None else float(row["mean"])


def reference_means(summary: pd.DataFrame, keys) -> dict:
    """Constant velocity's mean of each metric in ``keys`` (NaN when absent)."""
    return {key: cell_mean(summary, key, REFERENCE_SETTING, CONSTANT_VELOCITY) for key in keys}


def tex_across(value: str, ncols: int) -> str:
    """A reference's one value, italic, spanning the ``ncols`` setting columns of a LaTeX row."""
    return rf"\multicolumn{{{ncols}}}{{c}}{{\textit{{{value}}}}} \\"


def _has_references(summary: pd.DataFrame) -> list[str]:
    return [m for m in REFERENCES
            if ((summary.method == m) & (summary.setting == REFERENCE_SETTING)).any()]


def setting_header(cols: list[str], lead: str) -> list[str]:
    """The two LaTeX header lines naming the settings ``cols``, after the cell(s) ``lead``."""
    blank = " &" * lead.count("&")
    return [lead + " & " + " & ".join(rf"\textbf{{{setting_labels(s)[0]}}}" for s in cols)
            + r" \\",
            blank + " & " + " & ".join(rf"\textbf{{{setting_labels(s)[1]}}}"
                                       if setting_labels(s)[1] else "" for s in cols) + r" \\"]


def latex_float(caption: str, label: str, spec: str, rows: list[str]) -> str:
    """A ``table*`` float scaled to the text width: booktabs rules around ``rows``."""
    return "\n".join([r"\begin{table*}[t]", r"\centering", caption, rf"\label{{{label}}}",
                      r"\resizebox{\textwidth}{!}{%", rf"\begin{{tabular}}{{{spec}}}", r"\toprule",
                      *rows, r"\bottomrule", r"\end{tabular}%", "}", r"\end{table*}", ""])


def _table1_cells(summary: pd.DataFrame, tests: pd.DataFrame, key: str, method: str,
                  cols: list[str], text, bold) -> list[str]:
    """``method``'s Table I cells of metric ``key``: ``text(row)``, ``bold``-ed where better."""
    cells = {s: text(_lookup(summary, key, s, method)) for s in cols}
    return [bold(c) if getattr(_test_row(tests, key, s), "better", None) == method else c
            for s, c in cells.items()]


def table1_latex(summary: pd.DataFrame, tests: pd.DataFrame, caption_extra: str = "") -> str:
    """Table I as a ``table*`` float (colours ``bcrlcolor`` / ``bccolor``)."""
    cols = table_settings(summary, tests)
    colours = {BC_RL: "bcrlcolor", BC: "bccolor"}
    caption = (
        r"\caption{\textbf{BC-RL versus BC under six observation models.} Mean over seeds of "
        r"per-step (log divergence, overlap, offroad) and per-scenario (max log divergence, "
        r"overlap rate, offroad rate) metrics on the validation scenarios; lower is better. "
        r"Orange rows: BC-RL ($w_{BC}=1$, $w_{RL}=0.05$); blue rows: BC. Bold marks the "
        rf"better method where the difference is significant ({TEST_NAME}, "
        rf"$\alpha={ALPHA}$). {caption_extra}}}")
    lines = setting_header(cols, r"\textbf{Metric}")
    for metric in METRICS:
        lines.append(r"\midrule")
        for i, method in enumerate((BC_RL, BC)):
            cells = _table1_cells(summary, tests, metric.key, method, cols, _fmt_mean, tex_bold)
            lines.append(tex_row(metric.label[i], *[rf"\cellcolor{{{colours[method]}}}{text}"
                                                    for text in cells]))
        for method in _has_references(summary):
            value = _fmt_mean(_lookup(summary, metric.key, REFERENCE_SETTING, method))
            lines.append(rf"\quad\textit{{{METHOD_LABELS[method].lower()}}} & "
                         + tex_across(value, len(cols)))
    return latex_float(caption, "tab:results", "l" + "c" * len(cols), lines)


def _ci_text(row: pd.Series | None) -> str:
    if row is None:
        return MISSING
    mean, low, high = float(row["mean"]), float(row["ci_low"]), float(row["ci_high"])
    if not math.isfinite(low):
        return _fmt(mean)
    return f"{mean:.2f} ± {(high - low) / 2:.2f}"


def safety_verdicts(tests: pd.DataFrame) -> dict[str, str]:
    """Per setting, a one-line answer to "is BC-RL safer than BC?"."""
    safety = ("overlap", "overlap_rate", "offroad", "offroad_rate")
    verdicts, cells = {}, _cells(tests)
    for setting in table_settings(tests):
        rows = cells[(cells.setting == setting) & cells.metric.isin(safety)]
        if rows.empty:
            verdicts[setting] = "not evaluated"
            continue
        wins, losses = int((rows.better == BC_RL).sum()), int((rows.better == BC).sum())
        lower = int((rows["diff"] < 0).sum())
        word = {(True, False): "yes", (False, True): "no (BC is safer)",
                (True, True): "mixed"}.get((wins > 0, losses > 0), "no significant difference")
        verdicts[setting] = (f"{word}: BC-RL significantly better on {wins}/4 safety metrics, "
                             f"worse on {losses}/4, lower mean on {lower}/4")
    return verdicts


def table1_markdown(summary: pd.DataFrame, tests: pd.DataFrame, header: str = "") -> str:
    """Markdown Table I with CIs, effects, detectable effects and safety verdicts."""
    cols = table_settings(summary, tests)
    out = heading("# Table I: BC-RL vs BC", header)
    out += ["Mean over seeds ± 95% CI half-width (t-distribution over seed means). **Bold**: the "
            f"better method where the difference is significant ({TEST_NAME}, alpha={ALPHA}). "
            "Lower is better for every metric.", ""]
    out += md_head("metric", "method", *map(setting_short, cols))
    for metric in METRICS:
        name = " ".join(metric.label).replace("\\", "")
        for method in (BC_RL, BC):
            out.append(md_row(name, METHOD_LABELS[method], *_table1_cells(
                summary, tests, metric.key, method, cols, _ci_text, md_bold)))
        out += _reference_rows(summary, metric, name, len(cols))
    if len(_cells(tests)):
        out += ["", effects_markdown(tests).rstrip("\n"), "", power_markdown(tests).rstrip("\n")]
    out += ["", "## Is BC-RL safer than BC?", "",
            *(f"- **{setting_short(s)}**: {v}" for s, v in safety_verdicts(tests).items())]
    return "\n".join(out) + "\n"


def _metric_name(metric) -> str:
    return " ".join(metric.label).replace(chr(92), "").replace(" (%)", "")


def _reference_rows(summary: pd.DataFrame, metric, name: str, ncols: int) -> list[str]:
    """Markdown rows repeating each reference's one value (italic) in every setting column."""
    texts = {m: _ci_text(_lookup(summary, metric.key, REFERENCE_SETTING, m))
             for m in _has_references(summary)}
    return [md_row(name, f"*{METHOD_LABELS[m]}*", *[f"*{t}*"] * ncols) for m, t in texts.items()]


def vs_paper_markdown(summary: pd.DataFrame, tests: pd.DataFrame, header: str = "") -> str:
    """Our BC-RL / BC means next to the paper's Table I, cell by cell."""
    out = heading("# Our Table I next to the paper's", header)
    out += ["Paper: Grislain et al., Table I (WOMD validation, mean of 3 seeds). Absolute values "
            "are comparable only when both were computed on WOMD; on synthetic data compare the "
            "direction of the BC-RL minus BC difference.", ""]
    agree = total = 0
    for metric in METRICS:
        out += [f"## {_metric_name(metric)} ({metric.unit})", "",
                *md_head("setting", "ours BC-RL", "ours BC", "ours diff", "significant (95% CI)",
                         "paper BC-RL", "paper BC", "paper diff", "same direction")]
        for setting in SETTINGS:
            a, b = (cell_mean(summary, metric.key, setting, m) for m in (BC_RL, BC))
            pa, pb = PAPER_TABLE1[metric.key][setting]
            diff, pdiff = a - b, pa - pb
            sig = ""
            t = _test_row(tests, metric.key, setting)
            if t is not None and math.isfinite(float(t.p_value)):
                sig = (f"{'yes' if t.significant else 'no'} ([{_fmt(float(t.ci_low))}, "
                       f"{_fmt(float(t.ci_high))}], Holm p={float(t.p_holm):.3g})")
            same = MISSING
            if math.isfinite(diff):
                total += 1
                ok = (diff < 0) == (pdiff < 0) and diff != 0
                agree += ok
                same = "yes" if ok else "no"
            out.append(md_row(setting_short(setting), _fmt(a), _fmt(b), _fmt(diff),
                              sig or MISSING, f"{pa:.2f}", f"{pb:.2f}", f"{pdiff:+.2f}", same))
        out.append("")
    out.append(f"Direction of BC-RL minus BC agrees with the paper in {agree} of {total} "
               "evaluated cells.")
    return "\n".join(out) + "\n"


def _signed(value: float) -> str:
    """``+1.23`` / ``-1.23``; a value that rounds to zero prints as ``+0.00`` (never ``-0.00``)."""
    return f"{value:+.2f}" if round(value, 2) != 0 else "+0.00"


def _diff_text(row: pd.Series) -> str:
    """A difference and its interval: ``+0.12 [-0.03, +0.27]``."""
    return (f"{_signed(float(row['diff']))} [{_signed(float(row.ci_low))}, "
            f"{_signed(float(row.ci_high))}]")


def _interval_text(row: pd.Series | None) -> str:
    if row is None or not math.isfinite(float(row["diff"])):
        return MISSING
    text = _diff_text(row)
    return md_bold(text) if bool(row.significant) else text


def effects_markdown(tests: pd.DataFrame) -> str:
    """BC-RL minus BC per cell with its bootstrap interval; bold if significant."""
    cols = table_settings(tests)
    out = ["## BC-RL − BC (95% bootstrap interval over seeds and scenarios)", "",
           f"Negative: BC-RL lower (better). **Bold**: Holm-adjusted p < {ALPHA} over all "
           f"{len(_cells(tests))} cells ({TEST_NAME}).", "",
           *md_head("metric (unit)", *map(setting_short, cols))]
    out += [md_row(f"{_metric_name(metric)} ({metric.unit})",
                   *[_interval_text(_test_row(tests, metric.key, s)) for s in cols])
            for metric in METRICS]
    return "\n".join(out) + "\n"


def _power_rows(tests: pd.DataFrame) -> tuple[list[tuple], tuple[int, int, int]]:
    """Per metric (name, unit, [paper, MDE, Holm MDE cells]); the counts (>= MDE, >= Holm, n)."""
    cols = table_settings(tests)
    rows, n, k, kh = [], 0, 0, 0
    for metric in METRICS:
        paper, mde, holm = [], [], []
        for setting in cols:
            row = _test_row(tests, metric.key, setting)
            m, mh = (math.nan,) * 2 if row is None else (float(row.mde), float(row.mde_holm))
            if setting in PAPER_TABLE1[metric.key]:
                pa, pb = PAPER_TABLE1[metric.key][setting]
                effect = pa - pb
                paper.append((_signed(effect), math.isfinite(m) and abs(effect) >= m))
                if math.isfinite(m):
                    n, k, kh = n + 1, k + (abs(effect) >= m), kh + (abs(effect) >= mh)
            else:  # a setting beyond the paper: no paper effect to compare with
                paper.append((MISSING, False))
            mde.append((_fmt(m), False))
            holm.append((_fmt(mh), False))
        rows.append((_metric_name(metric), metric.unit, [paper, mde, holm]))
    return rows, (k, kh, n)


def power_markdown(tests: pd.DataFrame, header: str = "") -> str:
    """Minimum detectable effect (80% power) per cell next to the paper's BC-RL − BC."""
    cols = table_settings(tests)
    rows, (k, kh, n) = _power_rows(tests)
    n_cells = len(_cells(tests))
    out = heading("## Could the paper's effects be detected here?", header)
    out += [f"Minimum detectable effect (MDE): the smallest true BC-RL − BC difference a "
            f"two-sided test detects with {POWER:.0%} power, (z(1−α/2) + z({POWER})) × SE, SE "
            f"the bootstrap standard error of the difference at this run's seeds and scenarios; "
            f"at α={ALPHA} without correction, and at the strictest Holm level α/{n_cells} "
            f"(the first Holm step). Paper effect: BC-RL − BC in the paper's Table I, **bold** "
            f"where its size reaches the uncorrected MDE. Paper effects at least the MDE: {k} of "
            f"{n} cells (uncorrected), {kh} of {n} (Holm).", "",
            *md_head("metric (unit)", "row", *map(setting_short, cols))]
    labels = ("paper BC-RL − BC", f"MDE (α={ALPHA})", f"MDE (Holm, α={ALPHA}/{n_cells})")
    for name, unit, groups in rows:
        for label, cells in zip(labels, groups, strict=True):
            out.append(md_row(f"{name} ({unit})", label,
                              *[md_bold(t) if b else t for t, b in cells]))
    return "\n".join(out) + "\n"


def _tex_number(text: str) -> str:
    return text if text == MISSING else text.replace("+", "$+$").replace("-", "$-$")


def power_latex(tests: pd.DataFrame) -> str:
    """The MDE table as a ``table*`` float (label ``tab:power``) for the report."""
    cols = table_settings(tests)
    rows, (k, kh, n) = _power_rows(tests)
    n_cells = len(_cells(tests))
    caption = (
        rf"\caption{{\textbf{{Minimum detectable effect of BC-RL versus BC}} (80\% power, "
        rf"two-sided, normal approximation with the two-level bootstrap standard error at "
        rf"this run's seeds and scenarios), uncorrected ($\alpha={ALPHA}$) and at the strictest "
        rf"Holm level ($\alpha={ALPHA}/{n_cells}$), next to the paper's BC-RL $-$ BC from its "
        rf"Table~I (bold: at least the uncorrected MDE). The paper's effect reaches the MDE in "
        rf"{k} of {n} cells ({kh} with Holm).}}")
    lines = setting_header(cols, r"\textbf{Metric} &")
    labels = ("paper effect", "MDE", "MDE (Holm)")
    for name, unit, groups in rows:
        lines.append(r"\midrule")
        for i, (label, cells) in enumerate(zip(labels, groups, strict=True)):
            texts = [tex_bold(_tex_number(t)) if bold else _tex_number(t) for t, bold in cells]
            first = f"{name} ({unit.replace('%', chr(92) + '%')})" if i == 0 else ""
            lines.append(tex_row(first, label, *texts))
    return latex_float(caption, "tab:power", "ll" + "c" * len(cols), lines)


# ------------------------------------------------------------------ supplementary metrics
def _supplementary_rows(summary: pd.DataFrame, metrics) -> list[tuple]:
    """Per metric: (metric, [(method, italic, [cell per setting])])."""
    cols, present = table_settings(summary), set(summary.method)
    # the paper's two, then every other learned method present
    learned = [m for m in (BC_RL, BC) if m in present] or [BC_RL, BC]
    learned += [m for m in METHOD_LABELS if m in present and m not in learned
                and m not in REFERENCES]
    return [(metric, [(m, False, [_lookup(summary, metric.key, s, m) for s in cols])
                      for m in learned]
             + [(m, True, [_lookup(summary, metric.key, REFERENCE_SETTING, m)] * len(cols))
                for m in _has_references(summary)])
            for metric in metrics]


def _md(text: str) -> str:
    """Escape the Markdown table separator."""
    return text.replace("|", r"\|")


def supplementary_markdown(summary: pd.DataFrame, metrics, header: str = "") -> str:
    """The registry's metrics per setting and method, with their sources."""
    cols = table_settings(summary)
    out = heading("# Supplementary metrics (beyond Table I)", header)
    out += ["Per-scenario metrics of closed-loop driving benchmarks (definitions and sources: "
            "docs/metrics.md), mean over seeds ± 95% CI half-width (t-distribution over seed "
            "means); rates in %. `--`: not evaluated (e.g. CSVs written before the metric "
            "existed).", "",
            *md_head("metric (unit)", "method", *map(setting_short, cols))]
    for metric, groups in _supplementary_rows(summary, metrics):
        better = "higher" if metric.higher_is_better else "lower"
        name = _md(f"{metric.label} ({metric.unit}; {better} is better)")
        for method, italic, cells in groups:
            mark = "*" if italic else ""
            out.append(md_row(name, f"{mark}{METHOD_LABELS[method]}{mark}",
                              *[f"{mark}{_ci_text(c)}{mark}" for c in cells]))
    out += ["", *md_head("metric", "source")]
    return "\n".join(out + [md_row(_md(m.label), _md(m.source)) for m in metrics]) + "\n"


def _tex(text: str) -> str:
    return (text.replace("\\", r"\textbackslash{}").replace("%", r"\%").replace("_", r"\_")
            .replace("&", r"\&").replace("#", r"\#").replace("²", "$^2$").replace("³", "$^3$")
            .replace("≥", r"$\geq$").replace(">=", r"$\geq$").replace("|", r"$|$")
            .replace("<", "$<$"))


def supplementary_latex(summary: pd.DataFrame, metrics, caption_extra: str = "") -> str:
    """The supplementary table as a ``table*`` float (label ``tab:supplementary``)."""
    cols = table_settings(summary)
    caption = (
        r"\caption{\textbf{Supplementary closed-loop metrics} (nuPlan-, NAVSIM- and "
        r"Waymax-style, definitions in docs/metrics.md): mean over seeds on the validation "
        rf"scenarios; rates in \%. {caption_extra}}}")
    lines = setting_header(cols, r"\textbf{Metric} &")
    for metric, groups in _supplementary_rows(summary, metrics):
        lines.append(r"\midrule")
        arrow = r"$\uparrow$" if metric.higher_is_better else r"$\downarrow$"
        for i, (method, italic, cells) in enumerate(groups):
            first = f"{_tex(metric.label)} ({_tex(metric.unit)}) {arrow}" if i == 0 else ""
            name = METHOD_LABELS[method]
            texts = [_fmt_mean(c) for c in cells]
            row = tex_across(texts[0], len(cols)) if italic else tex_row(*texts)
            lines.append(f"{first} & " + (rf"\textit{{{name.lower()}}}" if italic else name)
                         + f" & {row}")
    return latex_float(caption, "tab:supplementary", "ll" + "c" * len(cols), lines)
