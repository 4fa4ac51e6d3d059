"""PPO and BC learn on a tiny maze; the study runs end to end; bad arguments fail clearly.

One small configuration (5x5 maze, GRU-16) is compiled once and shared by every test.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from tqdm import tqdm

from igdrivsim.errors import ConfigError
from maze import study as S
from maze.bc import BCConfig
from maze.ppo import PPOConfig

TINY = dataclasses.replace(
    S.PROFILES["smoke"], profile="test", size=5, max_steps=30, seeds=2, hidden=16,
    ppo=PPOConfig(num_envs=16, num_steps=32, num_minibatches=2, update_epochs=4, lr=5e-3),
    rl_full_updates=64, rl_partial_updates=8, chunk_updates=8,
    bc=BCConfig(num_envs=8, num_steps=64, epochs=4, num_minibatches=2, lr=1e-2),
    bc_chunk_epochs=1, eval_episodes=32, baselines=False)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One tiny study (PPO on full obs. long enough to learn, so BC has a real expert)."""
    out = tmp_path_factory.mktemp("maze")
    study = S.Study(TINY)
    summary = S.run_study(TINY, out / "out", out / "work", study=study,
                          command="python -m maze --out OUT")
    return study, out, summary


def test_each_program_compiles_once(run):
    """Both seed parts (one seed each) and every curve share one compiled program per
    function: no recompilation between stages, parts or chunks."""
    study, out, _ = run
    assert study.compiled() == dict.fromkeys(study.programs(), 1)
    meta = json.loads((out / "out/maze_config.json").read_text())
    assert meta["compiled_programs"] == study.compiled()


def test_provenance_records_the_run_alone(run):
    """``igdrivsim report provenance maze`` records the run's own command, machine,
    wall time and code for each of its outputs, and stamps its markdown table."""
    from igdrivsim.report import provenance

    _, out, _ = run
    written = provenance.record_maze(out / "out")
    assert "tables/maze_summary.md" in written and "maze_config.json" in written
    entry = provenance.load(out / "out")["figures/fig2_maze.png"]
    assert entry["command"] == "python -m maze --out OUT" and set(entry["stages"]) == {"maze"}
    assert entry["wall_s"] > 0 and "cores" in entry["device"]
    table = (out / "out/tables/maze_summary.md").read_text()
    assert table.splitlines()[2].startswith("Provenance: written by `python -m maze --out OUT`")


def test_ppo_learns_on_a_tiny_maze(run):
    _, out, _ = run
    curves = pd.read_csv(out / "out/figures/fig2_maze.csv")
    rl = curves[curves.curve == "rl_full"]
    start = rl[rl.progress == 0]["return"].mean()
    end = rl[rl.final]["return"].mean()
    assert end > start + 2.0, (start, end)
    assert end > 6.0  # 5x5 maze, goal at most 8 moves away: the optimum is above 7.5


def test_bc_loss_goes_down(run):
    _, out, _ = run
    losses = np.asarray(json.loads((out / "out/maze_config.json").read_text())[
        "bc_loss_per_chunk"])  # [chunks, curves]
    assert (losses[-1] < losses[0]).all(), losses
    assert losses[-1][0] < np.log(4) - 0.05, losses  # imitating a trained expert: below ln 4


def test_study_writes_every_output_and_resumes(run, capsys):
    study, tmp, summary = run
    out, work = tmp / "out", tmp / "work"
    for rel in S.OUTPUTS:
        assert (out / rel).stat().st_size > 0, rel
    assert list(summary.curve) == ["rl_full", "rl_partial", *S.BC_CURVES]
    curves = pd.read_csv(out / "figures/fig2_maze.csv")
    assert set(curves.seed) == {0, 1} and curves["final"].sum() == 5 * 2
    meta = json.loads((out / "maze_config.json").read_text())
    assert meta["config"]["size"] == 5 and meta["config"]["hidden"] == 16
    assert "timings_s" in meta
    first = pd.read_csv(out / "tables/maze_summary.csv")
    capsys.readouterr()
    # Same config again: nothing is recomputed.
    S.run_study(TINY, out, work, study=study)
    assert "up to date" in capsys.readouterr().out
    # Outputs removed but stage caches kept: resumes from the caches, same numbers.
    (out / "maze_config.json").unlink()
    again = S.run_study(TINY, out, work, study=study)
    pd.testing.assert_frame_equal(first, again.reset_index(drop=True), check_dtype=False)


def test_runs_are_deterministic(run):
    """A curve trained on all seeds at once repeats the study's, trained one seed part at a
    time (the parts' seeds keep their keys and initial parameters)."""
    study, out, _ = run
    assert S.seed_parts(TINY) == [(0,), (1,)]
    with tqdm(disable=True) as bar:
        rerun = pd.DataFrame(S.run_rl(study, "rl_partial", True, bar)["records"])
    curves = pd.read_csv(out / "out/figures/fig2_maze.csv")
    before = curves[curves.curve == "rl_partial"].reset_index(drop=True)
    np.testing.assert_allclose(rerun["return"], before["return"], rtol=1e-6)


@pytest.mark.parametrize("argv", [["--seeds", "0"], ["--hidden", "0"]])
def test_bad_arguments_exit_with_one_line(argv, capsys, tmp_path):
    assert S.main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("maze study: error:") and "\n" not in err


def test_bad_maze_config_raises():
    with pytest.raises(ConfigError):
        dataclasses.replace(TINY, size=6).validate()
    with pytest.raises(ConfigError):
        dataclasses.replace(TINY, receptive_field=7).validate()
