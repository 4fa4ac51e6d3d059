"""Every committed report file has a provenance entry; a run publishes only what its kind owns
(the default run keeps Table II of the --methods run, and the other way round)."""

from __future__ import annotations

from pathlib import Path

from igdrivsim.pipeline.runner import REPO_ROOT
from igdrivsim.report import provenance


def test_every_committed_table_and_figure_has_an_entry():
    paper = REPO_ROOT / "paper"
    files = provenance.load(paper)
    for sub in ("tables", "figures"):
        for path in sorted((paper / sub).iterdir()):
            assert f"{sub}/{path.name}" in files, f"{sub}/{path.name} has no provenance entry"
    assert provenance.missing(paper) == []
    for rel, entry in files.items():
        assert set(entry) == set(provenance.Entry.__dataclass_fields__), rel
        assert entry["run"] == provenance.owner(rel)
        if rel.endswith(".md"):  # the table states its entry in one line
            assert provenance.Entry(**entry).line() in (paper / rel).read_text()
        if entry["updates"] is not None and entry["updates"] < 1000:
            assert provenance.BELOW_TARGETS in entry["note"], rel


def test_the_methods_run_owns_what_the_report_writes_for_it():
    from igdrivsim.report.build import METHODS_OUTPUTS

    assert set(provenance.METHODS_FILES) == set(METHODS_OUTPUTS)


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


def test_runs_publish_what_they_own_and_keep_the_rest(tmp_path):
    paper = tmp_path / "paper"
    methods = _staged(tmp_path / "m", ["tables/table1.md", "tables/table2.md"], "methods run")
    assert provenance.publish(methods, paper, _entry("methods")) == [
        "tables/table1.md", "tables/table2.md", "generated/run.tex"]
    # the default run replaces Table I, keeps Table II (it writes none) and its entry
    default = _staged(tmp_path / "d", ["tables/table1.md"], "default run")
    published = provenance.publish(default, paper, _entry("default", "quick", 300))
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
    assert provenance.publish(again, paper, _entry("methods")) == ["tables/table2.md"]
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
