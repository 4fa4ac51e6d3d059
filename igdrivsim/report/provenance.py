"""Which command wrote each report file, and the code of each stage behind its numbers:
``paper/provenance.json`` (:class:`Entry`) and one line in each table. A run publishes the files
its kind owns, and another kind's only where missing. ``igdrivsim report provenance``."""

from __future__ import annotations

import datetime as _dt
import fnmatch
import re
import shlex
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from igdrivsim.errors import ConfigError
from igdrivsim.io import atomic_copy, atomic_write_json, atomic_write_text, read_json
from igdrivsim.machine import CODE_KEYS, code_label, code_state

FILE = "provenance.json"
SCHEMA = 2  # per-stage code (``stages``, ``mixed_commits``)
ABOUT = ("the command that wrote each file under this folder and the code (commit, dirty flag, "
         "diff hash) of each pipeline stage its numbers came from (igdrivsim.report.provenance)")
LINE_PREFIX = "Provenance: "
# what a run of each kind owns (relative to the paper folder): the methods run Table II's files
# (the report writes them only with methods beyond BC and BC-RL); everything else the default run
METHODS_FILES = ("tables/tests_all.csv", "tables/table2.md", "tables/table2.tex",
                 "figures/fig6_methods.pdf", "figures/fig6_methods.png")
OUTPUT_FOLDERS = ("tables", "figures", "generated")
OUTPUT_FILES = ("maze_config.json", "results.md")  # outputs outside those folders
BELOW_TARGETS = "its drivers are below the competence targets"
# the pipeline stages whose numbers a file holds (fnmatch patterns of stage names), by the
# file's path prefix; any other file: REPORT_STAGES (the report and what it reads)
STAGE_SOURCES = (
    (("figures/fig2", "figures/maze", "tables/maze", "maze_config.json"), ("maze",)),
    (("figures/fig1",), ("render",)),
    (("tables/speed_walk", "generated/speed_walk"), ("speed_walk", "report")),
    (("tables/real_logs",), ("data", "filter_*", "teacher", "train_*", "real_logs")),
    (("tables/reactive", "figures/fig7_reactive"),
     ("data", "filter_*", "teacher", "train_*", "evaluate_*", "reactive")),
)
REPORT_STAGES = ("data", "filter_*", "teacher", "train_*", "evaluate_*", "report")


def stages_behind(rel: str, stamped: Sequence[str]) -> list[str]:
    """The stages among ``stamped`` (kept in their order) whose numbers file ``rel`` holds."""
    patterns = next((p for prefixes, p in STAGE_SOURCES if rel.startswith(prefixes)),
                    REPORT_STAGES)
    return [s for s in stamped if any(fnmatch.fnmatchcase(s, p) for p in patterns)]


@dataclass(frozen=True)
class Entry:
    """How one file was written."""

    command: str  # the command that wrote it
    run: str  # default | methods: the kind of run that owns the file
    profile: str  # the profile the command ran (laptop, quick, gpu, smoke, paper)
    updates: int | None  # training updates of that profile (None: not a trained output)
    commit: str  # the stages' code (code_label, comma-separated)
    device: str  # CPU model and cores, or the accelerator; "device not recorded"
    wall_s: float | None  # the run's wall time (None: not recorded)
    date: str  # YYYY-MM-DD HH:MM UTC or YYYY-MM-DD
    note: str = ""
    stages: dict[str, dict] | None = None  # stage -> its code_state; None: not yet set

    @property
    def commits(self) -> list[str]:
        """The distinct code labels of the stages behind the file, in stage order."""
        return list(dict.fromkeys(code_label(s) for s in (self.stages or {}).values()))

    @property
    def mixed_commits(self) -> bool:
        """The stages behind the file ran different code."""
        return len(self.commits) > 1

    def with_stages(self, stages: Mapping[str, Mapping]) -> Entry:
        """This entry for a file whose numbers came from ``stages`` (name -> code_state)."""
        new = replace(self, stages={name: {k: state.get(k) for k in CODE_KEYS}
                                    for name, state in stages.items()})
        return replace(new, commit=", ".join(new.commits) or "unknown")

    def record(self) -> dict:
        """The entry as ``provenance.json`` holds it."""
        return {**asdict(self), "mixed_commits": self.mixed_commits}

    @classmethod
    def from_record(cls, record: Mapping) -> Entry:
        """An entry of ``provenance.json``."""
        return cls(**{k: v for k, v in record.items() if k in cls.__dataclass_fields__})

    def line(self) -> str:
        """The one-line statement of a table's header and the PDF."""
        wall = f"in {wall_text(self.wall_s)}" if self.wall_s else "wall time not recorded"
        updates = f", {self.updates:,} updates" if self.updates else ""
        note = f"; {self.note}" if self.note else ""
        code = (f"with stages at commits {', '.join(self.commits)}" if self.mixed_commits
                else f"at commit {self.commit}")
        return (f"{LINE_PREFIX}written by `{self.command}` (profile {self.profile}{updates}) "
                f"{code}, {self.device}, {wall}, {self.date}{note}.")


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
    return dict(read_json(path).get("files", {}))


def save(paper: Path, files: dict[str, dict]) -> Path:
    return atomic_write_json(Path(paper) / FILE, {
        "schema": SCHEMA, "about": ABOUT, "files": dict(sorted(files.items()))}, indent=2)


def outputs(folder: Path) -> list[str]:
    """Every output file under ``folder``, relative."""
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


def publish(staged: Path, paper: Path, entry: Entry,
            stages_of: Callable[[str], Mapping[str, Mapping]]) -> list[str]:
    """Publish the outputs ``entry.run`` owns (others only where missing), stamped; the paths."""
    staged, paper = Path(staged), Path(paper)
    atomic_write_text(staged / "generated" / "run.tex",
                      run_tex(entry.with_stages(stages_of("generated/run.tex"))))
    files = load(paper)
    published = []
    for rel in outputs(staged):
        if owner(rel) != entry.run and (paper / rel).exists():
            continue  # another run's file: never overwritten
        src, dst, this = staged / rel, paper / rel, entry.with_stages(stages_of(rel))
        if rel.endswith(".md"):
            atomic_write_text(dst, stamp_markdown(src.read_text(encoding="utf-8"), this.line()))
        else:
            atomic_copy(src, dst)
        files[rel] = this.record()
        published.append(rel)
    save(paper, files)
    return published


def derived(paper: Path, files_rel: Sequence[str], source: str, command: str,
            repo: Path) -> list[str]:
    """Record ``files_rel``, written by ``command`` from ``source``'s numbers; the files."""
    files = load(paper)
    if source not in files:
        raise ConfigError(f"{FILE}: no entry for the source {source!r}")
    base = Entry.from_record(files[source])
    note = f"derived from {source}" + (f"; {base.note}" if base.note else "")
    entry = replace(base, command=command, date=today(), note=note).with_stages(
        {**base.stages, "derive": code_state(repo)})
    for rel in files_rel:
        if not (paper / rel).is_file():
            raise ConfigError(f"{paper / rel}: no such output to record")
    return _record(paper, files, list(files_rel), entry)


def record_maze(paper: Path) -> list[str]:
    """Record the maze study's outputs, run alone, from its ``maze_config.json``."""
    paper = Path(paper)
    meta = read_json(paper / "maze_config.json")
    machine, code = meta.get("machine"), meta.get("code")
    if not isinstance(machine, dict) or not isinstance(code, dict) or not machine.get("command"):
        raise ConfigError(f"{paper / 'maze_config.json'}: no command, machine or code recorded "
                          "(written by an older maze study: rerun python -m maze --out PAPER)")
    entry = Entry(command=machine["command"], run="default",
                  profile=f"maze {meta['config']['profile']}", updates=None, commit="",
                  device=machine.get("cpu") or "device not recorded",
                  wall_s=meta.get("timings_s", {}).get("this_invocation_wall_s"),
                  date=machine.get("date") or today(),
                  note="the maze study run alone").with_stages({"maze": code})
    maze = [r for r in outputs(paper) if r.startswith(STAGE_SOURCES[0][0])]  # the study's files
    return _record(paper, load(paper), maze, entry)


def _record(paper: Path, files: dict, rels: list[str], entry) -> list[str]:
    """Give each of ``rels`` ``entry``'s record (its line atop a markdown table) and save."""
    for rel in rels:
        files[rel] = entry.record()
        if rel.endswith(".md"):
            path = paper / rel
            atomic_write_text(path, stamp_markdown(path.read_text(encoding="utf-8"),
                                                   entry.line()))
    save(paper, files)
    return rels


def missing(paper: Path) -> list[str]:
    """Outputs under ``paper`` without an entry."""
    files = load(paper)
    return [rel for rel in outputs(paper) if rel not in files]


def stage_check(files: Mapping[str, Mapping]) -> list[str]:
    """The entries lacking stage commits, or whose ``mixed_commits`` is wrong."""
    problems = []
    for rel, entry in sorted(files.items()):
        stages = entry.get("stages")
        if not isinstance(stages, dict) or not stages:
            problems.append(f"{rel}: no stage commits")
        elif lacking := [name for name, code in stages.items()
                         if not isinstance(code, dict) or not set(CODE_KEYS) <= set(code)]:
            problems.append(f"{rel}: stage commits missing for {', '.join(lacking)}")
        elif entry.get("mixed_commits") != Entry.from_record(entry).mixed_commits:
            problems.append(f"{rel}: mixed_commits does not match its stages")
    return problems


def command_line(args: Sequence[str]) -> str:
    return "bash scripts/reproduce.sh" + ("".join(f" {shlex.quote(a)}" for a in args))


def today() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def provenance_command(args, repo: Path) -> int:
    """``igdrivsim report provenance check|derived|maze`` (``check`` exits 1 on a gap)."""
    paper = Path(args.paper).resolve()
    if args.task == "check":
        lacking = missing(paper)
        problems = stage_check(load(paper))
        for line in [f"{rel}: no provenance entry" for rel in lacking] + problems:
            print(line)
        return 1 if lacking or problems else 0
    if args.task == "derived":
        if not (args.files and args.source and args.command):
            raise ConfigError("derived needs FILE..., --from SOURCE and --command CMD")
        written = derived(paper, args.files, args.source, args.command, repo)
    else:
        written = record_maze(paper)
    files = load(paper)
    for rel in written:
        print(f"{rel}: {files[rel]['command']} ({files[rel]['commit']})")
    return 0
