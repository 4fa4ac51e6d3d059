"""Bad input to evaluate, report, render and filter --merge: one clear line, exit status 2.

No training: the run folder is a smoke-profile config.json with a zero-filled checkpoint
(shapes from ``jax.eval_shape``, saved once per module).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from igdrivsim.cli import main
from igdrivsim.errors import DataError
from igdrivsim.evaluation import aggregate
from igdrivsim.evaluation.schema import PER_SCENARIO_COLUMNS


def _fails(capsys, argv: list[str], *expected: str) -> str:
    """Run the CLI; assert exit 2 and one stderr line holding every ``expected`` text."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for text in expected:
        assert text in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------------------- evaluate
@pytest.fixture(scope="module")
def run_template(tmp_path_factory) -> Path:
    """A loadable run folder: smoke config + a zero-filled checkpoint at step 4."""
    import jax
    import numpy as np

    from igdrivsim.training.config import get_profile, to_dict
    from igdrivsim.training.run import CHECKPOINTS, Checkpoints
    from igdrivsim.training.update import init_buffer, init_state, update_spec

    run = tmp_path_factory.mktemp("runs") / "run"
    run.mkdir()
    config = get_profile("smoke")
    (run / "config.json").write_text(json.dumps({"config": to_dict(config)}))
    spec = update_spec(config, teacher_policy=config.policy)
    params, opt_state = jax.eval_shape(lambda: init_state(config, spec))
    buffer = jax.eval_shape(lambda: init_buffer(config, spec))

    def zeros(tree):
        return jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), tree)

    ckpt = Checkpoints(run / CHECKPOINTS)
    ckpt.save(4, zeros(params), zeros(opt_state), None if buffer is None else zeros(buffer))
    ckpt.close()
    return run


@pytest.fixture
def run(run_template, tmp_path) -> Path:
    return Path(shutil.copytree(run_template, tmp_path / "run"))


def _evaluate(run: Path, tmp_path: Path, *extra: str) -> list[str]:
    return ["evaluate", str(run), "--data", str(tmp_path / "absent"), "--out",
            str(tmp_path / "out"), "--no-progress", *extra]


def test_intact_run_gets_past_the_checkpoint(run, tmp_path, capsys):
    # the template itself loads: the next complaint is about the (absent) data
    _fails(capsys, _evaluate(run, tmp_path), "validation data not found")


def test_malformed_run_config_names_the_file(run, tmp_path, capsys):
    (run / "config.json").write_text('{"config": ')
    _fails(capsys, _evaluate(run, tmp_path), str(run / "config.json"), "not readable JSON")


def test_garbage_checkpoint_metadata_is_one_line(run, tmp_path, capsys):
    for meta in (run / "checkpoints" / "4").rglob("_METADATA"):
        meta.write_text("garbage")
    _fails(capsys, _evaluate(run, tmp_path), str(run / "checkpoints" / "4"),
           "cannot restore checkpoint 4", "Error")


def test_truncated_checkpoint_data_is_one_line(run, tmp_path, capsys):
    step = run / "checkpoints" / "4"
    data = [p for p in step.rglob("*") if p.is_file() and p.parent.name == "d"]
    assert data
    for path in data:
        with open(path, "r+b") as f:
            f.truncate(10)
    line = _fails(capsys, _evaluate(run, tmp_path), str(step), "cannot restore checkpoint 4")
    assert len(line) < 600  # tensorstore's spec dump is cut off


def test_negative_limit_is_rejected(run, tmp_path, capsys):
    _fails(capsys, _evaluate(run, tmp_path, "--limit", "-1"), "--limit", "got -1")


# --------------------------------------------------------------------------------- render
@pytest.mark.parametrize(("option", "value", "expected"), [
    ("--panels", ",", "--panels"),
    ("--view", "0", "--view must be > 0, got 0"),
    ("--every", "0", "--every must be >= 1, got 0"),
    ("--record", "-1", "--record must be >= 0, got -1"),
])
def test_render_rejects_bad_option(option, value, expected, tmp_path, capsys):
    line = _fails(capsys, ["render", "--data", tmp_path / "absent.tfrecord", "--out",
                           tmp_path / "fig", option, value], expected)
    assert "--every" not in line or option == "--every"
    assert "--view" not in line or option == "--view"


# --------------------------------------------------------------------------------- report
def _scenario_csv(path: Path, rows: int = 3) -> str:
    lines = [",".join(PER_SCENARIO_COLUMNS)]
    lines += [f"full,bc,{seed},s{seed},3.0,0.0,0.0,1.0,0.0,0.0" for seed in range(rows)]
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(lines) + "\n"
    path.write_text(text)
    return text


def test_per_scenario_cut_off_mid_row(tmp_path, capsys):
    csv = tmp_path / "evals" / "per_scenario.csv"
    text = _scenario_csv(csv)
    csv.write_text(text[: text.rindex(",0.0,0.0,1.0")])  # last row loses its last 4 values
    with pytest.raises(DataError, match="cut off"):
        aggregate.load_evaluations([tmp_path / "evals"])
    _fails(capsys, ["report", "--evals", tmp_path / "evals", "--out", tmp_path / "report"],
           str(csv), "cut off")
    assert not (tmp_path / "report").exists()


def test_per_scenario_row_without_its_identifiers(tmp_path):
    csv = tmp_path / "evals" / "per_scenario.csv"
    text = _scenario_csv(csv)
    csv.write_text(text.replace("full,bc,1,s1,", "full,bc,1,,"))
    with pytest.raises(DataError, match=r"row 2 .*scenario_id"):
        aggregate.load_evaluations([tmp_path / "evals"])


def test_complete_per_scenario_still_reads(tmp_path):
    """Empty metrics are legitimate (a scenario without a valid logged step has none)."""
    csv = tmp_path / "evals" / "per_scenario.csv"
    text = _scenario_csv(csv)
    csv.write_text(text.replace("full,bc,2,s2,3.0,0.0,0.0,1.0,0.0,0.0",
                                "full,bc,2,s2,,0.0,0.0,,0.0,0.0"))
    _, per_scenario = aggregate.load_evaluations([tmp_path / "evals"])
    assert len(per_scenario) == 3


def test_report_missing_runs_folder(tmp_path, capsys):
    _scenario_csv(tmp_path / "evals" / "per_scenario.csv")
    missing = tmp_path / "no_runs_here"
    _fails(capsys, ["report", "--evals", tmp_path / "evals", "--out", tmp_path / "report",
                    "--runs", missing], "--runs", str(missing))


def test_report_corrupt_eval_config(tmp_path, capsys):
    _scenario_csv(tmp_path / "evals" / "per_scenario.csv")
    config = tmp_path / "evals" / "eval_config.json"
    config.write_text('{"profile": "smoke", ')
    _fails(capsys, ["report", "--evals", tmp_path / "evals", "--out", tmp_path / "report"],
           str(config))


# ---------------------------------------------------------------------------- filter merge
def test_merge_with_corrupt_shard_results(tmp_path, capsys):
    shards = tmp_path / "part0" / "shards"
    shards.mkdir(parents=True)
    (shards / "a.tfrecord.0123456789.json").write_text('{"file": "a.tfrecord", "entr')
    (shards / "b.tfrecord.0123456789.json").write_bytes(b"\xff\xfe garbage")
    line = _fails(capsys, ["filter", "--merge", tmp_path / "part0", "--out", tmp_path / "out"],
                  "partial filter result unreadable")
    assert str(shards / "a.tfrecord.0123456789.json") in line or str(
        shards / "b.tfrecord.0123456789.json") in line
    assert not (tmp_path / "out" / "manifest.jsonl").exists()
