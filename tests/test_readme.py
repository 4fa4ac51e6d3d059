"""The README as a newcomer uses it: every command it shows answers ``--help``, ``reproduce.sh
--help`` installs nothing, ``python -m maze`` leaves ``paper/`` alone, and every number in the
results block (and ``docs/results.md``) is the report's, not typed by hand."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
from pathlib import Path

import pytest

from igdrivsim import cli
from igdrivsim.report import results_doc
from igdrivsim.report.build import Provenance, build_report

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
OWN_MODULES = ("igdrivsim", "maze")


def _code(text: str) -> str:
    """Every shell block and inline code span of a markdown text, joined."""
    blocks = re.findall(r"```(?:bash|sh|console)\n(.*?)```", text, flags=re.S)
    rest = re.sub(r"```.*?```", "", text, flags=re.S)
    return "\n".join(blocks + re.findall(r"`([^`\n]+)`", rest))


def readme_commands() -> list[tuple[str, ...]]:
    """The commands the README shows: ``igdrivsim SUB [SUBSUB]``, ``python -m MODULE`` (ours),
    ``bash scripts/reproduce.sh``; derived from the README, so a new one is checked too."""
    code = _code(README.read_text(encoding="utf-8"))
    found: dict[tuple[str, ...], None] = {}
    for sub, rest in re.findall(r"(?<![\w/.-])igdrivsim ([a-z][a-z-]*)(?: ([a-z][a-z-]*))?",
                                code):
        found[("igdrivsim", sub, rest) if sub == "bench" and rest else ("igdrivsim", sub)] = None
    for module in re.findall(r"python -m ([\w.]+)", code):
        if module.split(".")[0] in OWN_MODULES:
            found[("python", module)] = None
    if "scripts/reproduce.sh" in code:
        found[("reproduce",)] = None
    return list(found)


def test_the_readme_shows_commands():
    commands = readme_commands()
    assert ("reproduce",) in commands and ("igdrivsim", "report") in commands
    assert len(commands) >= 8


@pytest.mark.parametrize("command", readme_commands(), ids=" ".join)
def test_every_readme_command_answers_help(command, capsys):
    if command[0] == "igdrivsim":
        main, argv = cli.main, list(command[1:])
    elif command[0] == "python":
        module = importlib.import_module(command[1])
        if not hasattr(module, "main"):
            module = importlib.import_module(command[1] + ".__main__")
        main, argv = module.main, []
    else:
        main, argv = importlib.import_module("igdrivsim.pipeline.cli").main, []
    with pytest.raises(SystemExit) as exc:
        main(argv + ["--help"])
    assert exc.value.code == 0, command
    assert "usage:" in capsys.readouterr().out


def test_reproduce_help_installs_nothing(tmp_path):
    """``--help`` with a Python that cannot import igdrivsim: help printed, pip never run."""
    calls = tmp_path / "calls"
    fake = tmp_path / "python"
    fake.write_text(f'#!/bin/sh\necho "$@" >> {calls}\nexit 1\n')
    fake.chmod(0o755)
    env = {**os.environ, "PYTHON": str(fake)}
    done = subprocess.run(["bash", str(ROOT / "scripts" / "reproduce.sh"), "--profile", "smoke",
                           "--help"], env=env, capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    assert "reproduce.sh" in done.stdout and "--profile" in done.stdout
    assert "-m pip" not in (calls.read_text() if calls.exists() else "")


def test_maze_writes_outside_paper_by_default():
    from maze import study

    parser = __import__("argparse").ArgumentParser()
    study.study_arguments(parser)
    out = parser.parse_args([]).out
    assert Path(out).parts[0] != "paper" and "paper" not in Path(out).parts


def test_report_fills_the_results_block_from_its_own_tables(tmp_path):
    """The report's markdown comes from the report's tables: the README block and results.md
    are rewritten between the markers only, and every number in the block is one the report
    wrote (``summary.csv`` / ``tests.csv``)."""
    from test_evaluation_report import fabricate  # the fabricated evaluations of that test

    paper = tmp_path / "paper"
    build_report([fabricate(tmp_path)], paper, Provenance(profile="smoke", data="synthetic"))
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{results_doc.BEGIN}\nstale 99.99\n{results_doc.END}\n\nrest\n")
    results = tmp_path / "docs" / "results.md"
    results_doc.write_markdown(paper, results, readme)
    text = readme.read_text()
    assert text.startswith("# x\n") and text.endswith(f"{results_doc.END}\n\nrest\n")
    block = text.split(results_doc.BEGIN)[1].split(results_doc.END)[0]
    assert "99.99" not in block and "[docs/results.md](docs/results.md)" in block
    assert block.strip() == results_doc.headline_markdown(paper).strip()
    import pandas as pd

    summary = pd.read_csv(paper / "tables" / "summary.csv")
    tests = pd.read_csv(paper / "tables" / "tests.csv")
    written = {f"{v:.2f}" for v in summary["mean"]} | {
        f"{abs(v):.2f}" for col in ("diff", "ci_low", "ci_high") for v in tests[col]}
    table = [line for line in block.splitlines() if line.startswith("| ")][1:]
    numbers = {n.lstrip("+-") for line in table for n in re.findall(r"[+-]?\d+\.\d\d", line)}
    paper_effects = {f"{abs(a - b):.2f}" for row in
                     results_doc.PAPER_TABLE1["offroad"].values() for a, b in [row]}
    assert numbers and numbers <= written | paper_effects
    page = results.read_text()
    assert "## Competence against the reference actors" in page and "Table I" in page
    assert "](../paper/tables/vs_paper.md)" in page  # links relative to docs/
    # from the tables alone (no evaluations): the same page
    again = tmp_path / "again.md"
    results_doc.write_markdown(paper, again)
    assert again.read_text().replace("](../paper/", "](paper/") == page.replace(
        "](../paper/", "](paper/")


def test_committed_results_are_the_reports():
    """README's block and docs/results.md are what the report writes from paper/'s tables
    (`igdrivsim report --from-tables --out paper --results docs/results.md --readme README.md`)."""
    paper = ROOT / "paper"
    if not (paper / "tables" / "summary.csv").is_file():
        pytest.skip("no committed tables")
    block = README.read_text(encoding="utf-8").split(results_doc.BEGIN)[1].split(
        results_doc.END)[0]
    assert block.strip() == results_doc.headline_markdown(paper).strip()
    runtime = README.read_text(encoding="utf-8").split(results_doc.RUNTIME_BEGIN)[1].split(
        results_doc.RUNTIME_END)[0]
    assert runtime.strip() == results_doc.runtime_markdown(paper).strip()
    assert (ROOT / "docs" / "results.md").read_text(encoding="utf-8") == \
        results_doc.results_markdown(paper, "../paper")


def test_readme_is_a_guide_not_a_diary():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    assert not re.search(r"[0-9a-f]{7,}", text), "a commit hash"
    for phrase in ("previous profile", "earlier profile", "not kept", "test suite took"):
        assert phrase not in text.lower()


def test_report_writes_the_prose_macros_from_its_tables(tmp_path):
    """``generated/results.tex`` holds each Table I cell as the report's tables have it, and
    counts over the BC-RL - BC cells (``igdrivsim.report.results_tex``)."""
    import pandas as pd
    from test_evaluation_report import fabricate

    paper = tmp_path / "paper"
    build_report([fabricate(tmp_path)], paper, Provenance(profile="smoke", data="synthetic"))
    results_doc.write_markdown(paper, tmp_path / "results.md")
    macros = dict(re.findall(r"\\newcommand\{\\(\w+)\}\{(.*)\}",
                             (paper / "generated" / "results.tex").read_text()))
    summary = pd.read_csv(paper / "tables" / "summary.csv")
    tests = pd.read_csv(paper / "tables" / "tests.csv")
    bc_full = summary[(summary.metric == "offroad") & (summary.setting == "full")
                      & (summary.method == "bc")]["mean"].iloc[0]
    assert macros["ResBCFullOffroad"] == f"{bc_full:.2f}"
    assert macros["ResCells"] == str(int((tests.method == "bc_rl").sum()))
    assert macros["ResSigHolm"] == str(int(tests.significant.astype(bool).sum()))


def test_every_result_macro_of_the_paper_is_generated_or_has_a_fallback():
    """The prose quotes results only through generated macros: each one it uses is written by
    the committed generated files and has a ``--`` fallback for a PDF built before a run."""
    paper = ROOT / "paper"
    main = (paper / "main.tex").read_text(encoding="utf-8")
    text = main + (paper / "findings.tex").read_text(encoding="utf-8")
    used = set(re.findall(r"\\((?:Res|Maze)[A-Za-z]+)", re.sub(r"(?<!\\)%.*", "", text)))
    fallback = set(re.findall(r"\\resultdefault\{\\(\w+)\}", main))
    assert used and used <= fallback
    generated = "".join(p.read_text(encoding="utf-8") for p in (paper / "generated").glob("*.tex"))
    if (paper / "generated" / "results.tex").is_file():
        assert used <= set(re.findall(r"\\newcommand\{\\(\w+)\}", generated))


def test_runtime_lines_state_each_runs_measured_time(tmp_path):
    """The README's run-time block comes from ``provenance.json``: the default run's wall time
    and machine, no GPU claimed without a gpu-profile entry, and the profiles' updates; in
    short lines, and with the same wall time as the results block's run line."""
    import json

    entry = dict(command="bash scripts/reproduce.sh", run="default", profile="laptop",
                 updates=1000, commit="x", device="AMD EPYC, 2 cores", wall_s=9330.0,
                 date="2026-11-27")
    (tmp_path / "provenance.json").write_text(json.dumps({"files": {"tables/table1.md": entry}}))
    block = results_doc.runtime_markdown(tmp_path)
    runs, profiles = block.split("Profiles")
    assert "2 h 35 min on AMD EPYC, 2 cores" in " ".join(runs.split())
    assert "1,000 updates" in runs and "no GPU run is recorded" in runs
    assert "Table II" not in runs
    assert "`quick`: 300 updates" in profiles
    assert all(len(line) <= 100 for line in block.splitlines() if "](" not in line)
    # the results block states the same run with the same wall time and rounding
    assert "2 h 35 min wall" in results_doc.run_line(tmp_path, commit=False)
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n{results_doc.RUNTIME_BEGIN}\nold\n{results_doc.RUNTIME_END}\n"
                      f"{results_doc.BEGIN}\n{results_doc.END}\n")
    text = results_doc.fill_block(readme.read_text(), block, "README", results_doc.RUNTIME_BEGIN,
                                  results_doc.RUNTIME_END)
    assert "old" not in text and block in text


def test_readme_generated_lines_are_short():
    """Prose lines of both generated blocks fit 100 columns (tables and links excepted)."""
    text = README.read_text(encoding="utf-8")
    for begin, end in ((results_doc.RUNTIME_BEGIN, results_doc.RUNTIME_END),
                       (results_doc.BEGIN, results_doc.END)):
        block = text.split(begin)[1].split(end)[0]
        long = [line for line in block.splitlines()
                if len(line) > 100 and not line.startswith("|") and "](" not in line]
        assert long == []


def test_the_run_times_say_what_holds_the_run_above_an_hour():
    """Two lanes: training 6,000 s of 7,000 s of stage time in 4,000 s of wall time, so at that
    overlap (1.75) an hour holds 6,300 s of stage time, 5,300 s of it training: 6,000 / 5,300."""
    import pandas as pd

    end = pd.Timestamp("2026-01-01 02:00:00")
    times = pd.DataFrame(dict(stage=["data", "train_bc", "train_bc_rl-1of2", "evaluate_bc"],
                              seconds=[400.0, 3000.0, 3000.0, 600.0]))
    times["finished"] = [str(end - pd.Timedelta(seconds=s)) for s in (3600, 0, 600, 0)]
    assert results_doc.wall_seconds(times) == pytest.approx(4000.0)
    text = results_doc.against_an_hour(times)
    assert "train 86%, evaluation 9%, data 6%" in text
    assert "training must shrink 1.1x for an hour" in text
    assert results_doc.against_an_hour(times[1:2]).startswith("Within an hour (50 min")
