"""Learning methods: the registry (the one place a method is named), and DAgger and ADVISOR
learning on a tiny case with a privileged teacher (smoke profile, toy straight roads)."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import write_toy_shard

from igdrivsim.errors import ConfigError
from igdrivsim.training import inputs, methods
from igdrivsim.training.config import get_profile, with_overrides
from igdrivsim.training.loop import train

SMOKE = get_profile("smoke")
STUDENT_SETTINGS = "circular_r4,random_masking"


def _lines(run: Path) -> list[dict]:
    return [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]


@pytest.fixture
def extra_method():
    """A method registered for one test (the registry is one dict that every reader shares)."""
    method = methods.register_method(methods.Method(
        "bc_rl_strong", "BC-RL (w_RL 0.5)", "#2CA02C", methods.get_method("bc_rl").loss,
        episodes=("logged", "rollout")))
    yield method
    del methods.METHODS[method.name]


def test_registry_order_and_what_each_method_collects():
    assert list(methods.METHODS)[:4] == ["bc", "bc_rl", "dagger", "advisor"]
    get = methods.get_method
    assert not get("bc").rollout and get("bc_rl").rollout and get("dagger").rollout
    assert get("dagger").teacher and get("advisor").teacher and get("advisor").aux_head
    assert "aggregate" in get("dagger").episodes and get("bc_rl").baseline == "bc"
    with pytest.raises(ConfigError, match="unknown learning method 'nope'"):
        get("nope")
    with pytest.raises(ConfigError, match="or its own, built by its collect hook"):
        methods.Method("x", "X", "red", get("bc").loss, episodes=("aggregate",))
    assert get("dagger").collect is not None and get("advisor").reports == "teacher_ce"


def test_the_registry_is_the_only_place_a_method_is_named():
    """No module outside igdrivsim/training/methods/ spells a method's name as a string,
    except igdrivsim/names.py, where the names, labels and colours are defined once."""
    root = Path(methods.__file__).resolve().parents[3]  # the repository
    assert (root / "igdrivsim" / "training" / "methods").is_dir()
    pattern = re.compile(r"""["'](bc|bc_rl|dagger|advisor)["']""")
    offenders = []
    for path in (root / "igdrivsim").rglob("*.py"):
        rel = path.relative_to(root).as_posix()
        if rel.startswith("igdrivsim/training/methods/"):
            continue
        for name in pattern.findall(path.read_text(encoding="utf-8")):
            if rel != "igdrivsim/names.py":
                offenders.append(f"{rel}: {name}")
    assert offenders == []


def test_configuration_reads_the_registry(extra_method):
    assert not with_overrides(SMOKE, ["training.method=bc"]).collects_rollout
    config = with_overrides(SMOKE, ["training.method=bc_rl_strong", "loss.w_rl=0.5"])
    assert config.validate().collects_rollout
    with pytest.raises(ConfigError, match="unknown learning method"):
        with_overrides(SMOKE, ["training.method=nope"]).validate()
    with pytest.raises(ConfigError, match="already registered"):
        methods.register_method(methods.Method("bc", "other", "red", extra_method.loss))
    with pytest.raises(ConfigError, match="needs a privileged teacher"):
        with_overrides(SMOKE, ["training.method=dagger"]).validate()
    advisor = with_overrides(SMOKE, ["training.method=advisor", "training.teacher=x"])
    assert advisor.validate().policy.aux_head  # the method decides the auxiliary head


def test_each_method_declares_and_checks_its_own_hyper_parameters():
    """ADVISOR's alpha and DAgger's buffer are their own params, typed and checked there;
    a run written when they were training fields still loads with its values."""
    from igdrivsim.training.config import from_dict, to_dict
    from igdrivsim.training.update import update_spec

    advisor = with_overrides(SMOKE, ["training.method=advisor", "training.teacher=x",
                                     "method.alpha=0.25", "method.aggregate_batches=3"])
    spec = update_spec(advisor.validate(), teacher_policy=SMOKE.policy)  # no teacher run read
    assert spec.params.alpha == 0.25 and not hasattr(spec.params, "aggregate_batches")
    dagger = with_overrides(SMOKE, ["training.method=dagger", "training.teacher=x",
                                    "method.aggregate_batches=3"])
    assert update_spec(dagger.validate(), SMOKE.policy).params.aggregate_batches == 3
    with pytest.raises(ConfigError, match="method.alpha must be finite and >= 0"):
        with_overrides(advisor, ["method.alpha=-1"]).validate()
    with pytest.raises(ConfigError, match="expected int"):
        with_overrides(dagger, ["method.aggregate_batches=2.5"])
    with pytest.raises(ConfigError, match="aggregate_batches must be >= 1"):
        with_overrides(dagger, ["method.aggregate_batches=0"]).validate()
    old = to_dict(dagger)
    old["training"].pop("method_params")
    old["training"] |= {"aggregate_batches": 3, "advisor_alpha": 1.0}
    assert from_dict(old) == dagger


def test_train_command_offers_every_registered_method(extra_method):
    from igdrivsim.training.commands import train_arguments

    parser = argparse.ArgumentParser()
    train_arguments(parser)
    for name in ("bc_rl_strong", "dagger", "advisor"):
        args = parser.parse_args(["--method", name, "--data", "d", "--out", "o"])
        assert args.method == name


# ------------------------------------------------------------------ taught methods, tiny case
@pytest.fixture(scope="module")
def toy_data(tmp_path_factory):
    """Eight toy straight-road scenarios (different speeds and lanes) as a tf.Example shard."""
    return write_toy_shard(tmp_path_factory.mktemp("toy"), SMOKE)


@pytest.fixture(scope="module")
def teacher_run(toy_data, tmp_path_factory):
    """A BC run with the full setting (the teacher) and its closed-loop validation curves."""
    out = tmp_path_factory.mktemp("runs") / "bc"
    config = with_overrides(SMOKE, ["training.method=bc", "observation.setting=full",
                                    "training.seeds=1"])
    train(config, toy_data, out, progress=False, log=lambda *_: None, val_data=toy_data)
    return out


def _taught(method: str, teacher: Path, data: str, out: Path, *sets: str) -> Path:
    config = with_overrides(SMOKE, [
        f"training.method={method}", f"observation.setting={STUDENT_SETTINGS}",
        f"training.teacher={teacher}", "training.num_updates=6", "training.lr=1e-2",
        "training.lr_end=1e-2", "training.ppo_epochs=4", "training.checkpoint_every=3",
        *sets])
    train(config, data, out, progress=False, log=lambda *_: None)
    return out


def test_dagger_aggregates_the_students_states_and_learns(teacher_run, toy_data, tmp_path):
    run = _taught("dagger", teacher_run, toy_data, tmp_path / "dagger",
                  "method.aggregate_batches=2")
    lines = _lines(run)
    # the data set grows by one batch of the student's episodes per update up to its capacity
    assert [x["aggregate_episodes"] for x in lines] == [4, 8, 8, 8, 8, 8]
    assert lines[-1]["teacher_ce"] < lines[0]["teacher_ce"]
    assert lines[-1]["bc_loss"] < lines[0]["bc_loss"]
    # the run loads for evaluation (its checkpoints also hold the buffer)
    from igdrivsim.training.run import Run

    config, params = Run.open(run).config, Run.open(run).params()
    assert config.training.method == "dagger" and jax.tree.leaves(params)[0].shape[:2] == (2, 2)


def test_advisor_weights_imitation_and_learns(teacher_run, toy_data, tmp_path):
    run = _taught("advisor", teacher_run, toy_data, tmp_path / "advisor",
                  "method.alpha=0.1")
    lines = _lines(run)
    assert all(0.0 < x["imitation_weight"] <= 1.0 for x in lines)
    assert lines[-1]["aux_teacher_ce"] < lines[0]["aux_teacher_ce"]
    assert lines[-1]["teacher_ce"] < lines[0]["teacher_ce"]
    assert "bc_loss" not in lines[0]  # it reads only its own episodes


def test_teacher_sees_full_observations_the_student_its_settings(teacher_run, toy_data):
    """One collection: the student's rollout is observed under its setting (circular r=4
    hides far road points), the same states fully observed for the teacher; the teacher's
    labels are its network on those full observations."""
    from igdrivsim.observation import get_setting, stack_settings
    from igdrivsim.policy.act import WARMUP_STEPS, example_observation, policy_rollout
    from igdrivsim.policy.network import init_params_per_seed, initial_carry, unroll_sequence
    from igdrivsim.training.privileged import load_teacher
    from igdrivsim.training.update import (
        collect,
        expert_sequences,
        init_buffer,
        teacher_labels,
        update_spec,
    )

    config = with_overrides(SMOKE, [
        "training.method=dagger", "observation.setting=circular_r4",
        f"training.teacher={teacher_run}", "training.seeds=1"]).validate()
    teacher_policy, teacher = load_teacher(str(teacher_run), config)
    spec = update_spec(config, teacher_policy)
    teacher = jax.tree.map(lambda x: x[0], teacher)
    dataset = inputs.Dataset.from_config(config, toy_data, spec.sim, need_states=True)
    rec, states = jax.tree.map(lambda x: jnp.asarray(x[0]), dataset.host_batch(0))
    params = jax.tree.map(lambda x: x[0], init_params_per_seed(
        config.policy, [jax.random.key(0)], example_observation(spec.obs)))
    buffer = jax.tree.map(lambda x: x[0, 0], init_buffer(config, spec))
    setting = jax.tree.map(lambda x: x[0], stack_settings(config.settings))
    key = jax.random.key(1)
    data, buffer, metrics = collect(spec, params, buffer, rec, states, setting, teacher, key)

    # the same rollout by hand (collect's keys), with the privileged observation returned
    b = rec.sdc_yaw.shape[0]
    k_ep, k_act, _ = jax.random.split(key, 3)
    keys = jax.random.split(k_ep, b)
    warm = jax.tree.map(lambda x: x[:WARMUP_STEPS], expert_sequences(spec, rec, setting, keys))
    carry, _, _ = unroll_sequence(spec.policy, params, initial_carry(spec.policy, (b,)), warm)
    full = get_setting("full")
    roll = policy_rollout(spec.policy, params, carry, states, setting, spec.obs, spec.sim,
                              keys, k_act, privileged=full)
    student = np.swapaxes(np.asarray(data["rollout_obs"].roadgraph_valid), 0, 1)
    np.testing.assert_array_equal(np.asarray(roll.obs.roadgraph_valid), student)
    assert np.asarray(roll.privileged_obs.roadgraph_valid).sum() > student.sum() > 0
    labels = teacher_labels(spec, teacher, expert_sequences(spec, rec, full, keys, WARMUP_STEPS),
                            roll.privileged_obs)
    np.testing.assert_allclose(np.swapaxes(np.asarray(labels), 0, 1),
                               np.asarray(data["teacher_logp"]), atol=1e-5)
    assert int(buffer.episodes) == b and float(metrics["aggregate_episodes"]) == b
