"""Which command wrote each report file: ``paper/provenance.json`` and one line in each table.

Every file under ``paper/`` that a run writes (tables, figures, generated LaTeX, the maze's
config) has an entry: the command, the kind of run that owns it (``default``: the default
run of ``scripts/reproduce.sh``; ``methods``: its ``--methods`` run with taught methods, which
owns Table II, ``tests_all.csv`` and Fig. 6), the profile and its updates, the commit, the
device, the run's wall time and date. A run *publishes* the files its kind owns from its work
folder into ``paper/``, and another kind's files only where they are missing (a fresh
``--out``): no run deletes or overwrites what another run wrote. Each markdown table and the
PDF (``generated/run.tex``) carry the same in one line.

``python -m igdrivsim.report.provenance backfill [--paper DIR]`` derives the entries of
committed files that have none from recorded metadata only: the commit that last wrote each
file (``git log``), the report's ``generated/provenance.tex`` and the training profile as of
that commit, the maze study's ``maze_config.json``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import re
import shlex
import subprocess
import sys
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from igdrivsim.errors import REPORTED, ConfigError, error_line
from igdrivsim.io import atomic_copy, atomic_write_json, atomic_write_text

FILE = "provenance.json"
SCHEMA = 1
LINE_PREFIX = "Provenance: "
# what a run of each kind owns (relative to the paper folder): the methods run Table II's files
# (igdrivsim.report.build.METHODS_OUTPUTS); everything else the default run
METHODS_FILES = ("tables/tests_all.csv", "tables/table2.md", "tables/table2.tex",
                 "figures/fig6_methods.pdf", "figures/fig6_methods.png")
OUTPUT_FOLDERS = ("tables", "figures", "generated")
OUTPUT_FILES = ("maze_config.json", "results.md")  # outputs outside those folders
BELOW_TARGETS = "its drivers are below the competence targets"


@dataclass(frozen=True)
class Entry:
    """How one file was written."""

    command: str  # the command that wrote it
    run: str  # default | methods: the kind of run that owns the file
    profile: str  # the profile the command ran (laptop, quick, gpu, smoke, paper)
    updates: int | None  # training updates of that profile (None: not a trained output)
    commit: str
    device: str  # CPU model and cores, or the accelerator; "device not recorded"
    wall_s: float | None  # the run's wall time (None: not recorded)
    date: str  # YYYY-MM-DD HH:MM UTC or YYYY-MM-DD
    note: str = ""

    def line(self) -> str:
        """The one-line statement of a table's header and the PDF."""
        wall = f"in {wall_text(self.wall_s)}" if self.wall_s else "wall time not recorded"
        updates = f", {self.updates:,} updates" if self.updates else ""
        note = f"; {self.note}" if self.note else ""
        return (f"{LINE_PREFIX}written by `{self.command}` (profile {self.profile}{updates}) at "
                f"commit {self.commit}, {self.device}, {wall}, {self.date}{note}.")


def wall_text(seconds: float) -> str:
    h, rest = divmod(int(round(seconds)), 3600)
    m, s = divmod(rest, 60)
    return f"{h} h {m:02d} min" if h else f"{m} min {s:02d} s"


def competence_note(profile: str, updates: int | None) -> str:
    """The quick profile's (and any budget below the laptop's) warning; empty otherwise."""
    # lazy: the training config pulls in JAX; provenance is read without it
    from igdrivsim.training.config import COMPETENT_UPDATES

    if profile in ("laptop", "quick", "gpu") and updates and updates < COMPETENT_UPDATES:
        return (f"{BELOW_TARGETS} ({updates:,} updates; the default trains "
                f"{COMPETENT_UPDATES:,})")
    return ""


def owner(relative: str) -> str:
    return "methods" if relative in METHODS_FILES else "default"


def load(paper: Path) -> dict[str, dict]:
    path = Path(paper) / FILE
    if not path.is_file():
        return {}
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise ConfigError(f"{path}: not readable JSON ({err})") from err
    return dict(record.get("files", {}))


def save(paper: Path, files: dict[str, dict]) -> Path:
    return atomic_write_json(Path(paper) / FILE, {
        "schema": SCHEMA,
        "about": "the command that wrote each file under this folder (igdrivsim.evaluation."
                 "provenance)",
        "files": dict(sorted(files.items()))}, indent=2)


def outputs(folder: Path) -> list[str]:
    """Every output file under ``folder`` (relative paths): the tables, figures and generated
    LaTeX, and the maze's config."""
    folder = Path(folder)
    found = [str(p.relative_to(folder)) for sub in OUTPUT_FOLDERS if (folder / sub).is_dir()
             for p in sorted((folder / sub).iterdir()) if p.is_file()]
    return found + [name for name in OUTPUT_FILES if (folder / name).is_file()]


def stamp_markdown(text: str, line: str) -> str:
    """``text`` with its provenance line (after the title, or first) set to ``line``."""
    lines = [ln for ln in text.splitlines() if not ln.startswith(LINE_PREFIX)]
    head = lines[:1] if lines and lines[0].startswith("#") else []
    rest = lines[len(head):]
    while rest and not rest[0].strip():
        rest.pop(0)
    return "\n".join([*head, *([""] if head else []), line, "", *rest]) + "\n"


def run_tex(entry: Entry) -> str:
    """``generated/run.tex``: ``\\ProvRun``, the entry's line for the PDF."""
    text = re.sub(r"([_%&#$])", r"\\\1", entry.line()[len(LINE_PREFIX):])
    text = re.sub(r"`([^`]*)`", lambda m: r"\texttt{" + m.group(1).replace("--", "-{}-") + "}",
                  text)
    return ("% Generated by igdrivsim.report.provenance; do not edit.\n"
            f"\\newcommand{{\\ProvRun}}{{{text}}}\n")


def publish(staged: Path, paper: Path, entry: Entry) -> list[str]:
    """Copy the outputs under ``staged`` that ``entry.run`` owns into ``paper`` (and the
    others only where ``paper`` lacks them), stamp the markdown tables, write
    ``generated/run.tex`` for the PDF, and record an entry per published file in
    ``paper/provenance.json``. Returns the published paths (relative)."""
    staged, paper = Path(staged), Path(paper)
    atomic_write_text(staged / "generated" / "run.tex", run_tex(entry))
    files = load(paper)
    published = []
    for rel in outputs(staged):
        if owner(rel) != entry.run and (paper / rel).exists():
            continue  # another run's file: never overwritten
        src, dst = staged / rel, paper / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if rel.endswith(".md"):
            atomic_write_text(dst, stamp_markdown(src.read_text(encoding="utf-8"),
                                                  entry.line()))
        else:
            atomic_copy(src, dst)
        files[rel] = asdict(entry)
        published.append(rel)
    save(paper, files)
    return published


# ------------------------------------------------------------------------------ the backfill
def _git(*args: str, cwd: Path) -> str:
    try:
        return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError) as err:
        raise ConfigError(f"git {' '.join(args)} failed in {cwd}: {err}") from err


def _show(commit: str, path: Path, repo: Path) -> str:
    """``path`` as committed in ``commit``."""
    return _git("show", f"{commit}:{path.relative_to(repo)}", cwd=repo)


def _tex_macros(text: str) -> dict[str, str]:
    return dict(re.findall(r"\\newcommand\{\\(\w+)\}\{([^}]*)\}", text))


def _updates_at(commit: str, profile: str, repo: Path) -> int | None:
    """``num_updates`` of ``profile`` in ``igdrivsim/training/config.py`` as of ``commit``."""
    try:
        source = _git("show", f"{commit}:igdrivsim/training/config.py", cwd=repo)
    except ConfigError:
        return None
    body = re.search(rf"def {profile}\(\)[\s\S]*?(?=\ndef |\Z)", source)
    found = re.search(r"num_updates=(\d[\d_]*)", body.group(0)) if body else None
    return int(found.group(1).replace("_", "")) if found else None


def derive(rel: str, paper: Path, repo: Path) -> Entry:
    """The entry of committed file ``rel`` from what was recorded when it was written."""
    commit, date, subject = _git("log", "-1", "--format=%h%x00%ad%x00%s", "--date=short",
                                 "--", str((paper / rel).relative_to(repo)),
                                 cwd=repo).split("\x00")
    wall = re.search(r"\((\d+) min (\d+) s\)", subject)
    wall_s = int(wall.group(1)) * 60 + int(wall.group(2)) if wall else None
    run = owner(rel)
    command = "bash scripts/reproduce.sh" + (
        " --methods bc,bc_rl,dagger,advisor" if run == "methods" else "")
    if rel.startswith(("figures/fig2", "figures/maze", "tables/maze")) or rel in OUTPUT_FILES:
        meta = json.loads(_show(commit, paper / "maze_config.json", repo))
        return Entry(command=f"python -m maze --profile {meta['config']['profile']}",
                     run=run, profile=f"maze {meta['config']['profile']}", updates=None,
                     commit=commit, device=f"JAX device {meta.get('device', 'unknown')}",
                     wall_s=meta.get("timings_s", {}).get("this_invocation_wall_s"), date=date,
                     note="the maze study (the default run's maze stage copies it since)")
    prov = _tex_macros(_show(commit, paper / "generated" / "provenance.tex", repo))
    profile, code = prov.get("ProvProfile", "unknown"), prov.get("ProvCommit", commit)
    updates = _updates_at(code, profile, repo) if profile != "unknown" else None
    note = competence_note("quick" if updates and updates < 1000 else profile, updates)
    if profile == "laptop" and updates is not None and updates < 1000:
        note = (f"the laptop profile as of {code} trained {updates} updates, today's quick "
                f"profile; {note}")
    if rel.startswith(("figures/fig1", "tables/speed_walk", "generated/speed_walk")):
        return Entry(command=command, run=run, profile=profile, updates=None, commit=commit,
                     device="device not recorded", wall_s=wall_s, date=date,
                     note="no trained policy in it")
    return Entry(command=command, run=run, profile=profile, updates=updates, commit=code,
                 device="device not recorded", wall_s=wall_s, date=prov.get("ProvDate", date),
                 note=note)


def backfill(paper: Path, repo: Path, stamp: bool = True) -> list[str]:
    """Entries for the committed outputs under ``paper`` that have none; with ``stamp`` their
    markdown tables get the provenance line. Returns the files given an entry."""
    files, added = load(paper), []
    tracked = set(_git("ls-files", str(paper.relative_to(repo)), cwd=repo).splitlines())
    for rel in outputs(paper):
        if rel in files or str((paper / rel).relative_to(repo)) not in tracked:
            continue
        entry = derive(rel, paper, repo)
        files[rel] = asdict(entry)
        if stamp and rel.endswith(".md"):
            path = paper / rel
            atomic_write_text(path, stamp_markdown(path.read_text(encoding="utf-8"),
                                                   entry.line()))
        added.append(rel)
    run = paper / "generated" / "run.tex"
    if not run.exists() and "tables/table1.tex" in files:  # the PDF's line: Table I's run
        atomic_write_text(run, run_tex(Entry(**files["tables/table1.tex"])))
        files["generated/run.tex"] = files["tables/table1.tex"]
        added.append("generated/run.tex")
    save(paper, files)
    return added


def missing(paper: Path) -> list[str]:
    """Outputs under ``paper`` without an entry."""
    files = load(paper)
    return [rel for rel in outputs(paper) if rel not in files]


def command_line(args: Sequence[str]) -> str:
    return "bash scripts/reproduce.sh" + ("".join(f" {shlex.quote(a)}" for a in args))


def today() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def main(argv: Iterable[str] | None = None) -> int:
    """``backfill``: derive the missing entries from recorded metadata; ``check``: list the
    outputs without an entry (exit 1 when there is one)."""
    repo = Path(__file__).resolve().parents[2]
    parser = argparse.ArgumentParser(prog="python -m igdrivsim.report.provenance",
                                     description=main.__doc__)
    parser.add_argument("action", choices=("backfill", "check"))
    parser.add_argument("--paper", default=str(repo / "paper"), help="the report folder")
    args = parser.parse_args(list(argv) if argv is not None else None)
    try:
        paper = Path(args.paper).resolve()
        if args.action == "backfill":
            for rel in backfill(paper, repo):
                print(f"{rel}: {load(paper)[rel]['command']} ({load(paper)[rel]['commit']})")
            return 0
        lacking = missing(paper)
        for rel in lacking:
            print(f"{rel}: no provenance entry")
        return 1 if lacking else 0
    except REPORTED as err:
        print(f"provenance: error: {error_line(err)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
