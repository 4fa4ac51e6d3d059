"""What the documentation claims, checked mechanically (fast: no training, no pipeline run).

One test per kind of claim: every command answers ``--help`` (exit 0) and its help shows each
option's default (``igdrivsim`` subcommands, the ``python -m`` modules the docs name, every
``scripts/*.sh``); every repository path the docs name exists; every ``igdrivsim.xxx`` module
they name imports; the README's output layout is what the pipeline writes, and the list of
``paper/``'s files in ``docs/usage.md`` is what the report holds.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import os
import re
import subprocess
from pathlib import Path

import pytest
from conftest import run_help

from igdrivsim import cli
from igdrivsim.report.commands import ACTIONS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs").rglob("*.md"))]
OWN_MODULES = ("igdrivsim", "maze")
SCRIPTS = sorted((ROOT / "scripts").glob("*.sh"))
# paths the docs name on purpose that are not in the repository
NOT_IN_REPOSITORY = {
    "paper/main.pdf": "built by `make -C paper`, not committed",
    "igdrivsim/training/methods/bc_rl_scaled.py": "the file the method recipe has you create",
    "igdrivsim/training/methods/bc_entropy.py": "the file ARCHITECTURE's method example creates",
    "docs/metrics_description.md": "nuPlan's documentation, cited in docs/metrics.md",
}


def _text(doc: Path) -> str:
    return doc.read_text(encoding="utf-8")


# ------------------------------------------------------------------------------ --help
def _undocumented_defaults(parser: argparse.ArgumentParser) -> list[str]:
    """The options with a default (not None, not a flag) whose help does not state it."""
    formatter = parser._get_formatter()
    missing = []
    for action in parser._actions:
        if (not action.option_strings or action.help == argparse.SUPPRESS or action.nargs == 0
                or action.default in (None, argparse.SUPPRESS) or action.default == []):
            continue
        if "default" not in (formatter._get_help_string(action) or "").lower():
            missing.append(action.option_strings[-1])
    return missing


def _subparser(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.ArgumentParser:
    for name in argv:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


SUBCOMMANDS = ([[name] for name in cli.COMMANDS] + [["bench", n] for n in cli.BENCHES]
               + [["report", n] for n in ACTIONS])


@pytest.mark.parametrize("argv", SUBCOMMANDS, ids=" ".join)
def test_every_igdrivsim_subcommand_shows_its_defaults(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv + ["--help"])
    assert exc.value.code == 0 and "usage:" in capsys.readouterr().out
    parser = cli.build_parser()
    parser.parse_known_args(argv)[0]._configure()
    assert _undocumented_defaults(_subparser(parser, argv)) == [], "igdrivsim " + " ".join(argv)


def doc_modules() -> list[str]:
    """Every ``python -m MODULE`` of ours that the README or docs/ name."""
    found = {m for doc in DOCS for m in re.findall(r"python3? -m ([\w.]+)", _text(doc))}
    return sorted(m for m in found if m.split(".")[0] in OWN_MODULES)


def test_the_docs_name_python_modules():
    assert "maze" in set(doc_modules())


@pytest.mark.parametrize("module", doc_modules())
def test_every_python_module_the_docs_name_shows_its_defaults(module, monkeypatch, capsys):
    main = importlib.import_module(module)
    if not hasattr(main, "main"):
        main = importlib.import_module(module + ".__main__")
    seen = run_help(main.main, [], monkeypatch, capsys)
    assert seen and _undocumented_defaults(seen[0]) == [], module


@pytest.fixture
def nothing_runs(tmp_path):
    """An environment in which every program a script could start (python, igdrivsim,
    taskset, nproc) only records that it was called."""
    calls = tmp_path / "calls"
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name in ("python", "python3", "igdrivsim", "taskset", "nproc", "pip"):
        fake = bin_dir / name
        fake.write_text(f'#!/bin/sh\necho "{name} $@" >> {calls}\nexit 1\n')
        fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
           "PYTHON": str(bin_dir / "python")}
    return env, calls


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_every_script_answers_help_with_its_defaults_and_runs_nothing(script, nothing_runs):
    env, calls = nothing_runs
    done = subprocess.run(["bash", str(script), "--help"], env=env, capture_output=True,
                          text=True, timeout=30, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout and "default" in done.stdout.lower(), script.name
    ran = calls.read_text().splitlines() if calls.exists() else []
    # reproduce.sh asks the Python whether igdrivsim is importable (to print the full help)
    assert [c for c in ran if not c.startswith("python -c import igdrivsim")] == [], ran


def test_reproduce_help_shows_the_pipelines_defaults():
    done = subprocess.run(["bash", str(ROOT / "scripts" / "reproduce.sh"), "--help"],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    assert "usage:" in done.stdout and "(default: " in done.stdout


# ------------------------------------------------------------------------------ paths
def _expand(path: str) -> list[str]:
    """``a.{md,tex}`` -> ``a.md``, ``a.tex``."""
    match = re.search(r"\{([^{}]*)\}", path)
    if not match:
        return [path]
    return [p for part in match.group(1).split(",")
            for p in _expand(path[:match.start()] + part + path[match.end():])]


def named_paths() -> list[tuple[str, str]]:
    """(doc, path): every repository path a doc names in a code span (starting at a top-level
    entry of the repository) or in a relative link (resolved against the doc's folder)."""
    top = {p.name for p in ROOT.iterdir() if not p.name.startswith(".")} | {".ci"}
    out = []
    for doc in DOCS:
        text = _text(doc)
        prose = re.sub(r"```.*?```", "", text, flags=re.S)
        for span in re.findall(r"`([^`\n]+)`", prose):
            path = span.split("::")[0]
            if " " in path or "<" in path or path.split("/")[0] not in top or "/" not in path:
                continue
            out += [(doc.name, p) for p in _expand(path)]
        for link in re.findall(r"\]\(([^)\s]+)\)", text):
            target = link.split("#")[0]
            if target and not re.match(r"[a-z]+:", target):
                path = os.path.relpath((doc.parent / target).resolve(), ROOT)
                out.append((doc.name, path))
    return out


def test_every_path_the_docs_name_exists():
    paths = named_paths()
    assert len(paths) > 50
    missing = sorted({f"{doc}: {path}" for doc, path in paths if path not in NOT_IN_REPOSITORY
                      and not ((ROOT / path).exists() or "*" in path and any(ROOT.glob(path)))})
    assert missing == []


# ------------------------------------------------------------------------------ modules
def named_modules() -> list[str]:
    return sorted({m for doc in DOCS
                   for m in re.findall(r"(?<![\w/.-])(igdrivsim(?:\.\w+)+)", _text(doc))})


def _resolve(name: str) -> object:
    """The module ``name``, or an attribute of the longest module prefix of it."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        prefix = ".".join(parts[:i])
        try:
            obj = importlib.import_module(prefix)
        except ModuleNotFoundError as err:
            if err.name != prefix:
                raise
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(name)


def test_every_igdrivsim_module_the_docs_name_imports():
    names = named_modules()
    assert len(names) > 10
    broken = []
    for name in names:
        try:
            _resolve(name)
        except (ImportError, AttributeError) as err:
            broken.append(f"{name}: {err!r}")
    assert broken == []


# ------------------------------------------------------------------------------ layout
def _code_block_from(text: str, first: str) -> list[str]:
    """The lines of the fenced block whose first line starts with ``first``."""
    blocks, block = [], None
    for line in text.splitlines():
        if line.startswith("```"):
            block = [] if block is None else blocks.append(block)
        elif block is not None:
            block.append(line)
    for block in blocks:
        if block and block[0].startswith(first):
            return block
    raise AssertionError(f"no code block starting with {first!r}")


def readme_work_names() -> set[str]:
    """The top-level names of the work folder in the README's output layout."""
    lines = _code_block_from(_text(README), "outputs/<profile>/")
    work = lines[1:next(i for i, line in enumerate(lines) if line.startswith("paper/"))]
    return {m for line in work
            for m in re.findall(r"(?:^|\s)([a-z_]+(?:/|\.(?:json|lock|md)(?!\w)))", line)}


def pipeline_work_names() -> set[str]:
    """What the pipeline writes directly under its work folder: ``<...>.work / "NAME"``."""
    names = set()
    for path in (ROOT / "igdrivsim" / "pipeline").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div)
                    and isinstance(node.left, ast.Attribute) and node.left.attr == "work"
                    and isinstance(node.right, ast.Constant) and isinstance(node.right.value,
                                                                             str)):
                value = node.right.value
                names.add(value if "." in value else value + "/")
    return names


def test_readme_output_layout_is_what_the_pipeline_writes():
    code = pipeline_work_names()
    assert {"runs/", "evals/", "logs/", "stages/", "wall.json"} <= code
    assert readme_work_names() == code


def test_readme_names_runs_as_the_pipeline_splits_them():
    from igdrivsim.names import SETTINGS
    from igdrivsim.pipeline import planning

    parts = planning.split_grid(["bc", "bc_rl"], SETTINGS, 4,
                                lambda method, n: float(n * (3 if method == "bc_rl" else 1)))
    names = {p.name for p in parts}
    assert "bc" in names and any(re.fullmatch(r"bc_rl-\d+of\d+", n) for n in names)
    layout = "\n".join(_code_block_from(_text(README), "outputs/<profile>/"))
    assert "runs/<part>/" in layout and "(bc)" in layout
    assert re.search(r"\(bc_rl-\d+of\d+\)", layout)


def _listed(lines: list[str]) -> dict[str, set[str]]:
    """``{folder: file names}`` of a layout list of ``paper/``: ``a, b (.md, .tex)`` groups and
    bare ``name.ext`` names, under the folder named at the start of a line."""
    found: dict[str, set[str]] = {}
    folder, text = "", {}
    for line in lines[1:]:
        head = re.match(r"\s*(\w+/)\s", line)
        folder = head.group(1).rstrip("/") if head else (folder if line.startswith("     ")
                                                           else "")
        text[folder] = text.get(folder, "") + " " + (line[head.end():] if head else line)
    for folder, body in text.items():
        body = " ".join(body.split())
        names = found.setdefault(folder, set())
        for group, exts in re.findall(r"((?:\w+, )*\w+) \((\.\w+(?:, \.\w+)*)\)", body):
            names |= {f"{stem}{ext}" for stem in group.split(", ") for ext in exts.split(", ")}
        body = re.sub(r"((?:\w+, )*\w+) \((\.\w+(?:, \.\w+)*)\)", "", body)
        names |= set(re.findall(r"\b\w+\.(?:md|tex|csv|json|png|pdf)\b", body))
    return found


def test_the_listed_report_files_are_the_committed_report():
    lines = _code_block_from(_text(ROOT / "docs" / "usage.md"), "paper/")
    listed = _listed(lines)
    for folder in ("tables", "figures", "generated"):
        committed = {p.name for p in (ROOT / "paper" / folder).iterdir() if p.is_file()}
        assert listed[folder] == committed, folder
    assert listed[""] <= {p.name for p in (ROOT / "paper").iterdir()}


# ------------------------------------------------------------------------------ Table II
def _table2_methods(page: str) -> set[str]:
    section = page.split("## Table II")[1].split("\n## ")[0]
    return {row.split(" | ")[1] for row in section.splitlines() if row.startswith("| ")
            and not row.startswith("| metric") and not row.startswith("|---")
            and not row.split(" | ")[1].startswith("*")}


@pytest.mark.parametrize("own_table", [True, False], ids=["table2.md", "tests_all.csv only"])
def test_results_page_table2_has_every_method_of_tests_all(own_table, tmp_path):
    """docs/results.md's Table II has a row for BC and every method ``tests_all.csv`` compares
    with it, from the methods run's own ``table2.md`` or, without it, from the comparisons."""
    import shutil

    import pandas as pd

    from igdrivsim.report import results_doc
    from igdrivsim.report.methods_table import method_label

    tables = ROOT / "paper" / "tables"
    if not (tables / "tests_all.csv").is_file():
        pytest.skip("no committed Table II")
    paper = tmp_path / "paper"
    shutil.copytree(ROOT / "paper", paper, ignore=shutil.ignore_patterns("*.pdf", "*.png"))
    if not own_table:
        (paper / "tables" / "table2.md").unlink()
    expected = {method_label(m) for m in
                {"bc", *pd.read_csv(tables / "tests_all.csv").method.astype(str)}}
    page = results_doc.results_markdown(paper)
    assert _table2_methods(page) == expected
    if own_table:
        committed = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
        assert _table2_methods(committed) == expected
