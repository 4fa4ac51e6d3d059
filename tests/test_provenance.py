"""Every committed report file has a provenance entry; a run publishes only what its kind owns
(the default run keeps Table II of the --methods run, and the other way round); each entry
names the code of the stages behind it, from their stamps (a republish keeps their commits)."""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path

import pytest

from igdrivsim import cli, machine
from igdrivsim.pipeline.runner import REPO_ROOT
from igdrivsim.report import provenance


def report_provenance(argv):
    return cli.main(["report", "provenance", *argv])

FIELDS = set(provenance.Entry.__dataclass_fields__)


def test_every_committed_table_and_figure_has_an_entry():
    paper = REPO_ROOT / "paper"
    files = provenance.load(paper)
    for sub in ("tables", "figures"):
        for path in sorted((paper / sub).iterdir()):
            assert f"{sub}/{path.name}" in files, f"{sub}/{path.name} has no provenance entry"
    assert provenance.missing(paper) == []
    assert provenance.stage_check(files) == []  # every entry names its stages' code
    for rel, entry in files.items():
        assert set(entry) == FIELDS | {"mixed_commits"}, rel
        assert entry["run"] == provenance.owner(rel)
        if rel.endswith(".md"):  # the table states its entry in one line
            assert provenance.Entry.from_record(entry).line() in (paper / rel).read_text()
        if entry["updates"] is not None and entry["updates"] < 1000:
            assert provenance.BELOW_TARGETS in entry["note"], rel


def _staged(root: Path, names: list[str], text: str) -> Path:
    for rel in names:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(f"# {rel}\n\n{text}\n")
    return root


def _entry(run: str, profile: str = "laptop", updates: int = 1000) -> provenance.Entry:
    return provenance.Entry(command="bash scripts/reproduce.sh", run=run, profile=profile,
                            updates=updates, commit="abc1234", device="test CPU, 2 cores",
                            wall_s=9000.0, date="2026-11-27 00:00 UTC",
                            note=provenance.competence_note(profile, updates))


def _code(commit: str, dirty: bool = False) -> dict:
    return {"commit": commit, "dirty": dirty, "diff_hash": "0123456789ab" if dirty else None}


def _at(commit: str):
    """``stages_of`` of publish: every file from a report stage run at ``commit``."""
    return lambda rel: {"report": _code(commit)}


def test_runs_publish_what_they_own_and_keep_the_rest(tmp_path):
    paper = tmp_path / "paper"
    methods = _staged(tmp_path / "m", ["tables/table1.md", "tables/table2.md"], "methods run")
    assert provenance.publish(methods, paper, _entry("methods"), _at("abc1234")) == [
        "tables/table1.md", "tables/table2.md", "generated/run.tex"]
    # the default run replaces Table I, keeps Table II (it writes none) and its entry
    default = _staged(tmp_path / "d", ["tables/table1.md"], "default run")
    published = provenance.publish(default, paper, _entry("default", "quick", 300), _at("abc1234"))
    assert "tables/table1.md" in published and "tables/table2.md" not in published
    assert "methods run" in (paper / "tables/table2.md").read_text()
    table1 = (paper / "tables/table1.md").read_text().splitlines()
    assert table1[0] == "# tables/table1.md" and table1[2].startswith(provenance.LINE_PREFIX)
    assert provenance.BELOW_TARGETS in table1[2] and "default run" in table1[4]
    files = provenance.load(paper)
    assert files["tables/table2.md"]["run"] == "methods"
    assert files["tables/table1.md"]["profile"] == "quick"
    # a later --methods run does not overwrite the default run's Table I
    again = _staged(tmp_path / "m2", ["tables/table1.md", "tables/table2.md"], "methods again")
    assert provenance.publish(again, paper, _entry("methods"), _at("abc1234")) == [
        "tables/table2.md"]
    assert "default run" in (paper / "tables/table1.md").read_text()
    assert r"\newcommand{\ProvRun}" in (paper / "generated/run.tex").read_text()


def test_the_recorded_command_is_the_one_typed(tmp_path):
    """A samples cache found on the machine is not written into the command as ``--samples``;
    a ``--samples`` that was typed is."""
    from igdrivsim.pipeline.cli import build_parser, pipeline_from_args

    found = tmp_path / "real.tfrecord"
    found.write_bytes(b"")
    args = build_parser().parse_args([])
    plain = pipeline_from_args(args)
    plain.samples = str(found)  # as if the cache had been found
    assert plain.command_text() == "bash scripts/reproduce.sh"
    typed = pipeline_from_args(build_parser().parse_args(["--samples", str(found)]))
    assert typed.command_text() == f"bash scripts/reproduce.sh --samples {found}"


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c",
                           "commit.gpgsign=false", *args], cwd=repo, check=True,
                          capture_output=True, text=True).stdout.strip()


def test_code_state_records_the_commit_the_dirty_flag_and_the_diff_hash(tmp_path):
    repo = tmp_path / "repo"
    (repo / "paper").mkdir(parents=True)
    _git(repo, "init", "-q")
    (repo / "code.py").write_text("x = 1\n")
    (repo / "paper" / "table.md").write_text("| a |\n")
    _git(repo, "add", "code.py", "paper/table.md")
    _git(repo, "commit", "-qm", "one")
    head = _git(repo, "rev-parse", "--short", "HEAD")
    assert machine.code_state(repo) == {"commit": head, "dirty": False, "diff_hash": None}
    (repo / "paper" / "table.md").write_text("| b |\n")  # the pipeline's own output: clean
    assert machine.code_state(repo)["dirty"] is False
    (repo / "code.py").write_text("x = 2\n")
    dirty = machine.code_state(repo)
    diff = subprocess.run(["git", "diff", "HEAD", "--", "code.py"], cwd=repo, check=True,
                          capture_output=True).stdout
    assert dirty == {"commit": head, "dirty": True,
                     "diff_hash": hashlib.sha256(diff).hexdigest()[:12]}
    (repo / "code.py").write_text("x = 3\n")  # other code, same commit: another hash
    assert machine.code_state(repo)["diff_hash"] not in (None, dirty["diff_hash"])
    _git(repo, "commit", "-qam", "two")
    assert machine.code_state(repo)["commit"] not in (head, None)
    # not a git checkout (an installed package), or a folder inside one: unknown, no error
    (tmp_path / "plain").mkdir()
    (repo / "sub").mkdir()
    for where in (tmp_path / "plain", repo / "sub", tmp_path / "absent"):
        assert machine.code_state(where) == machine.UNKNOWN_CODE


def test_check_fails_when_a_published_file_lacks_its_stage_commits(tmp_path, capsys):
    paper = tmp_path / "paper"
    staged = _staged(tmp_path / "d", ["tables/table1.md"], "default run")
    provenance.publish(staged, paper, _entry("default"), _at("abc1234"))
    check = ["check", "--paper", str(paper)]
    assert report_provenance(check) == 0
    good = provenance.load(paper)
    assert good["tables/table1.md"]["stages"] == {"report": _code("abc1234")}
    for broken, message in (({"report": {"dirty": False, "diff_hash": None}},
                             "stage commits missing for report"),
                            ({}, "no stage commits"), (None, "no stage commits")):
        provenance.save(paper, {**good, "tables/table1.md": {
            **good["tables/table1.md"], "stages": broken}})
        capsys.readouterr()
        assert report_provenance(check) == 1, broken
        assert f"tables/table1.md: {message}" in capsys.readouterr().out
    # a publish whose stages are unknown to it records that, and the check fails
    provenance.publish(staged, paper, _entry("default"), lambda rel: {})
    assert report_provenance(check) == 1


def test_the_about_text_names_modules_that_exist_and_help_shows_defaults(tmp_path, capsys):
    import importlib
    import re

    provenance.save(tmp_path, {})
    about = json.loads((tmp_path / provenance.FILE).read_text())["about"]
    named = re.findall(r"igdrivsim(?:\.\w+)+", about)
    assert named == ["igdrivsim.report.provenance"]
    for module in named:
        importlib.import_module(module)
    with pytest.raises(SystemExit) as exit_:
        report_provenance(["--help"])
    assert exit_.value.code == 0
    # argparse wraps lines at spaces and after hyphens (a checkout named wt-x): compare unwrapped
    flat = "".join(capsys.readouterr().out.split())
    assert "".join(f"(default: {REPO_ROOT / 'paper'})".split()) in flat


def test_republishing_from_cached_stages_keeps_their_commits(tmp_path, monkeypatch):
    """Stages stamp the code they ran; publishing reads the stamps, not today's HEAD: a
    republish keeps the commits, a stage rerun at another commit makes the file mixed."""
    from igdrivsim.pipeline import planning
    from igdrivsim.pipeline.profiles import PROFILES
    from igdrivsim.pipeline.stages import Pipeline

    head = {"code": _code("aaaaaaa")}
    monkeypatch.setattr(machine, "code_state", lambda repo: dict(head["code"]))

    def pipe() -> Pipeline:
        p = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper", quiet=True,
                     methods=("bc", "bc_rl"))
        p._machine = planning.Machine(2, "test CPU")  # no device detection
        return p

    noop = [["python", "-c", "pass"]]
    first = pipe()
    for name in ("data", "train_bc", "train_dagger", "evaluate_bc", "maze", "report"):
        assert first.stage(name, noop)  # train_dagger: another run's (not this run's methods)
    _staged(first.staged, ["tables/table1.md", "tables/maze_summary.md"], "numbers")
    assert "tables/table1.md" in first.publish()
    files = provenance.load(first.paper)
    table1 = files["tables/table1.md"]
    assert set(table1["stages"]) == {"data", "train_bc", "evaluate_bc", "report"}
    assert table1["commit"] == "aaaaaaa" and table1["mixed_commits"] is False
    assert files["tables/maze_summary.md"]["stages"] == {"maze": _code("aaaaaaa")}

    head["code"] = _code("bbbbbbb", dirty=True)  # HEAD moved on; the stages are cached
    second = pipe()
    assert second.stage("report", noop) is False
    (second.paper / "tables" / "table1.md").unlink()  # missing: republished
    assert "tables/table1.md" in second.publish()
    again = provenance.load(second.paper)["tables/table1.md"]
    assert again["stages"] == table1["stages"] and again["commit"] == "aaaaaaa"

    (second.work / "stages" / "evaluate_bc.json").unlink()  # one stage reruns at bbbbbbb
    third = pipe()
    assert third.stage("evaluate_bc", noop) is True
    (third.paper / "tables" / "table1.md").unlink()
    third.publish()
    mixed = provenance.load(third.paper)["tables/table1.md"]
    assert mixed["mixed_commits"] is True
    assert mixed["stages"]["evaluate_bc"] == _code("bbbbbbb", dirty=True)
    assert mixed["stages"]["report"] == _code("aaaaaaa")
    both = "stages at commits aaaaaaa, bbbbbbb-dirty (diff 0123456789ab)"
    assert mixed["commit"] == "aaaaaaa, bbbbbbb-dirty (diff 0123456789ab)"
    assert both in (third.paper / "tables" / "table1.md").read_text()
    assert both in (third.paper / "generated" / "run.tex").read_text()
    assert provenance.stage_check(provenance.load(third.paper)) == []


def test_derived_files_name_their_command_and_the_code_of_both_steps(tmp_path, capsys):
    """A figure redrawn from a run's tables outside the pipeline keeps the run's stages and
    adds the redrawing code's: its entry says the stages ran under different commits."""
    paper = tmp_path / "paper"
    old = _entry("default").with_stages({"report": _code("abc1234")}).record()
    (paper / "tables").mkdir(parents=True)
    (paper / "figures").mkdir()
    (paper / "tables" / "seed_means.csv").write_text("x\n")
    (paper / "figures" / "fig3.png").write_text("png")
    (paper / "tables" / "summary.md").write_text("# Summary\n\nrows\n")
    provenance.save(paper, {"tables/seed_means.csv": old})
    assert report_provenance(["derived", "figures/fig3.png", "tables/summary.md", "--from",
                            "tables/seed_means.csv", "--command", "python -m redraw",
                            "--paper", str(paper)]) == 0
    files = provenance.load(paper)
    fig = provenance.Entry.from_record(files["figures/fig3.png"])
    assert fig.command == "python -m redraw" and set(fig.stages) == {"report", "derive"}
    assert fig.stages["report"]["commit"] == old["commit"] and fig.mixed_commits
    assert files["figures/fig3.png"]["mixed_commits"] is True
    assert "derived from tables/seed_means.csv" in fig.note
    assert provenance.stage_check(files) == []
    assert (paper / "tables" / "summary.md").read_text().splitlines()[2] == fig.line()
    assert files["tables/seed_means.csv"] == old  # the source's entry untouched
    assert report_provenance(["derived", "figures/fig3.png", "--paper", str(paper)]) == 2
    assert "derived needs FILE" in capsys.readouterr().err
