"""The smoke profile of ``scripts/reproduce.sh`` end to end, in process (shared compiles).

One pipeline run (module fixture): synthetic data -> filter -> train (three observation settings
trained together, one beyond the paper's six (occlusion), x {BC, BC-RL}) -> evaluate
(+ references) -> maze smoke -> render -> report.
Then: every expected output exists and parses, a rerun skips every stage, and re-running
evaluation gives identical tables.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from igdrivsim.errors import ConfigError
from igdrivsim.evaluation.registry import SCENARIO_COLUMNS
from igdrivsim.evaluation.schema import ORIGIN_COLUMNS, PER_STEP_COLUMNS
from igdrivsim.pipeline.cli import main as pipeline_main
from igdrivsim.pipeline.profiles import PROFILES
from igdrivsim.pipeline.runner import REPO_ROOT, StageError
from igdrivsim.pipeline.stages import Pipeline

SETTING = "circular_r4"
SETTINGS = ("full", SETTING, "occlusion")


def make(tmp: Path) -> Pipeline:
    return Pipeline(PROFILES["smoke"], tmp / "work", tmp / "work" / "paper",
                       in_process=True, quiet=True, settings=SETTINGS)


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("smoke")
    pipe = make(tmp)
    pipe.run()
    return pipe


def test_every_output_exists_and_parses(done):
    paper, work = done.paper, done.work
    for stem in ("fig1_observations", "fig2_maze", "fig3_metrics"):
        assert (paper / "figures" / f"{stem}.pdf").read_bytes().startswith(b"%PDF")
        from PIL import Image

        with Image.open(paper / "figures" / f"{stem}.png") as im:
            assert im.size[0] > 200 and im.size[1] > 100
    tex = (paper / "tables" / "table1.tex").read_text()
    assert r"\begin{table*}" in tex and tex.count(r"\midrule") == 6
    md = (paper / "tables" / "table1.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| log divergence | BC-RL"))
    assert row.count("--") == 4  # four settings not trained in this test, three with numbers
    assert md.splitlines()[[i for i, line in enumerate(md.splitlines())
                            if line.startswith("| metric | method")][0]].endswith(
        "| Mask p=.7 | Occlusion |")  # the registered extra setting: a column after the six
    assert "Expert (discretised replay)" in md and "Constant velocity" in md
    assert "| Circ r=4 |" in (paper / "tables" / "vs_paper.md").read_text()
    prov = (paper / "generated" / "provenance.tex").read_text()
    assert r"\newcommand{\ProvProfile}{smoke}" in prov and "synthetic" in prov
    assert (paper / "generated" / "verdicts.tex").read_text().count(r"\item") == 7
    results = (paper / "results.md").read_text()  # the report's page, from these tables
    assert "## Competence against the reference actors" in results and "| Occlusion |" in results
    assert "| train_bc |" in results  # stage times from WORK/stages (run_times.csv)
    for method in ("bc", "bc_rl"):
        run = method  # one run per method: every setting in one program
        assert (work / "runs" / run / "DONE").is_file()
        curves = pd.read_json(work / "runs" / run / "curves.jsonl", lines=True)
        assert set(curves.setting) == set(SETTINGS) and curves.log_divergence.notna().any()
        steps = pd.read_csv(work / "evals" / run / "per_step.csv")
        scen = pd.read_csv(work / "evals" / run / "per_scenario.csv")
        assert list(steps.columns) == list(PER_STEP_COLUMNS)
        assert list(scen.columns) == list(SCENARIO_COLUMNS) + list(ORIGIN_COLUMNS)
        assert (scen.source == scen.scenario_id).all() and (scen.logged_sdc == 1).all()
        assert set(scen.method) == {method} and scen.seed.nunique() == PROFILES["smoke"].seeds
        assert set(scen.setting) == set(SETTINGS)
        assert steps.step.max() == 80 and scen[["overlap", "offroad"]].isin([0, 1]).all().all()
        info = json.loads((work / "evals" / run / "eval_config.json").read_text())
        assert info["settings"] == list(SETTINGS) and info["actions"] == "sample"
        trained = json.loads((work / "runs" / run / "config.json").read_text())
        assert info["trained"]["code"] == trained["code"] and "commit" in trained["code"]
        assert info["trained"]["num_updates"] == trained["num_updates"] > 0
    refs = pd.read_csv(work / "evals" / "references" / "per_scenario.csv")
    assert set(refs.method) == {"expert", "constant_velocity"}
    assert refs[refs.method == "expert"].log_divergence.max() < 0.2
    # every driver under log replay and IDM agents: Table I's companion and Fig. 7
    reactive = (paper / "tables" / "reactive.md").read_text()
    assert "## at-fault overlap rate (%)" in reactive and "| Circ r=4 | BC-RL |" in reactive
    assert "| -- | Expert (its own log) |" in reactive and "| Occlusion | BC |" in reactive
    assert (paper / "figures" / "fig7_reactive.pdf").read_bytes().startswith(b"%PDF")
    idm = json.loads((work / "evals_idm" / "bc" / "eval_config.json").read_text())
    assert idm["sim"]["agents"] == "idm" and idm["sim"]["idm"]["desired_speed"] == 30.0
    assert info["sim"]["agents"] == "log"
    for stage in ("data", "filter_training", "maze", "render", "report", "reactive"):
        assert (work / "logs" / f"{stage}.log").is_file()
        assert (work / "stages" / f"{stage}.json").is_file()


def test_rerun_skips_and_reevaluation_gives_same_tables(done, capsys):
    paper, work = done.paper, done.work
    before = (paper / "tables" / "table1.md").read_bytes()
    again = make(work.parent)
    again.run()
    assert again.ran == set()  # everything complete: nothing ran
    # Force one evaluation to run again: same numbers, hence the same tables.
    (work / "stages" / "evaluate_bc.json").unlink()
    third = make(work.parent)
    third.run()
    tex = shutil.which("latexmk") or (shutil.which("pdflatex") and shutil.which("bibtex"))
    assert third.ran == {"evaluate_bc", "report", "reactive"} | ({"pdf"} if tex else set())
    assert _without_provenance(paper / "tables" / "table1.md") == _without_provenance(before)


def _without_provenance(table) -> list[str]:
    """A markdown table's lines but its provenance line (which has the date and wall time)."""
    from igdrivsim.report.provenance import LINE_PREFIX

    text = table.decode() if isinstance(table, bytes) else table.read_text()
    return [ln for ln in text.splitlines() if not ln.startswith(LINE_PREFIX)]


def test_every_output_has_the_provenance_entry_the_committed_report_has(done):
    from igdrivsim.report import provenance

    assert provenance.missing(done.paper) == []
    produced = provenance.load(done.paper)
    committed = provenance.load(REPO_ROOT / "paper")
    assert "tables/table1.md" in produced and "figures/fig1_observations.png" in produced
    assert provenance.stage_check(produced) == []  # every file names its stages' code
    git = (REPO_ROOT / ".git").exists()
    per_stage = {"stages", "mixed_commits"}  # beyond the committed schema 1 entries
    for rel, entry in produced.items():
        assert entry["command"].startswith("bash scripts/reproduce.sh --profile smoke --out ")
        assert entry["profile"] == "smoke" and entry["run"] == "default"
        assert all(isinstance(c["commit"], str) == git for c in entry["stages"].values()), rel
        if rel in committed:  # the same kind of run writes it, with the same fields
            assert committed[rel]["run"] == entry["run"]
            assert set(committed[rel]) - per_stage == set(entry) - per_stage
    assert {"report", "train_bc", "evaluate_bc", "evaluate_references"} <= set(
        produced["tables/table1.md"]["stages"])
    assert set(produced["figures/fig2_maze.png"]["stages"]) == {"maze"}
    line = next(ln for ln in (done.paper / "tables" / "table1.md").read_text().splitlines()
                if ln.startswith(provenance.LINE_PREFIX))
    assert "--profile smoke" in line and "cores" in line


def test_failing_stage_names_stage_and_log(tmp_path):
    pipe = make(tmp_path)
    with pytest.raises(StageError, match=r"stage 'evaluate_x' failed .*evaluate_x\.log"):
        pipe.stage("evaluate_x", [["igdrivsim", "evaluate", tmp_path / "no_run", "--data",
                                   tmp_path, "--out", tmp_path / "o"]])
    assert "not a training run" in (tmp_path / "work" / "logs" / "evaluate_x.log").read_text()
    assert not (tmp_path / "work" / "stages" / "evaluate_x.json").exists()


def test_work_folder_refuses_other_data(tmp_path):
    make(tmp_path).check_work_folder()
    make(tmp_path).check_work_folder()  # same options: fine
    other = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper",
                        train_data="womd/training", val_data="womd/validation")
    with pytest.raises(ConfigError, match="another train_data"):
        other.check_work_folder()


def test_changed_command_reruns_stage_and_overrides_are_checked(tmp_path, capsys):
    def sub():
        return Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "work" / "paper",
                           quiet=True)

    ok = [["python", "-c", "print('one')"]]
    assert sub().stage("tiny", ok) is True
    assert sub().stage("tiny", ok) is False  # same command: skipped
    assert sub().stage("tiny", [["python", "-c", "print('two')"]]) is True
    make(tmp_path).check_work_folder()
    changed = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "work" / "paper",
                          overrides=("training.num_updates=7",))
    with pytest.raises(ConfigError, match="another overrides"):
        changed.check_work_folder()
    assert pipeline_main(["--profile", "smoke", "--out", str(tmp_path / "x"),
                    "--set", "training.no_such_field=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("reproduce: error:") and "no_such_field" in err[-1]
