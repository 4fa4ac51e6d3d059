"""Metrics beyond Table I: constructed trajectories, the real WOMD expert, and the registry as
the one place a metric is named (CSV columns, supplementary table and figure)."""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from flax import struct

from igdrivsim.data.scenario import CURRENT_INDEX, DT, NUM_STEPS, Trajectory
from igdrivsim.evaluation import aggregate, registry, rollout
from igdrivsim.evaluation.registry import SCENARIO_COLUMNS
from igdrivsim.evaluation.schema import PER_SCENARIO_COLUMNS
from igdrivsim.report import figures, tables
from igdrivsim.simulator import episode_metrics as em
from igdrivsim.simulator.state import SdcTrajectory

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "womd" / (
    "motion_data_one_example.tfrecord")
T = np.arange(NUM_STEPS) * DT
PACKAGE = Path(registry.__file__).resolve().parents[1]


@struct.dataclass
class FinalState:
    """The fields of a final :class:`SimState` the episode metrics read."""

    sdc: SdcTrajectory
    log: Trajectory
    sdc_index: jax.Array
    timestep: jax.Array
    agents: None = None  # log-replayed objects


def _poses_from_speed(speed, yaw_rate=None):
    """Integrate speed (and yaw rate) profiles ``[T]`` into ``(x, y, yaw, vx, vy)``."""
    yaw_rate = np.zeros(NUM_STEPS) if yaw_rate is None else yaw_rate
    yaw = np.concatenate([[0.0], np.cumsum(yaw_rate[:-1] * DT)])
    vx, vy = speed * np.cos(yaw), speed * np.sin(yaw)
    x = np.concatenate([[0.0], np.cumsum(vx[:-1] * DT)])
    y = np.concatenate([[0.0], np.cumsum(vy[:-1] * DT)])
    return x, y, yaw, vx, vy


def make_state(sim, log=None, others=()):
    """A final state stand-in: the simulated SDC ``sim`` and its log ``log`` (default: the
    same), plus other objects ``(x, y, yaw, vx, vy, valid)`` with 4.5 x 2 m boxes."""
    log = sim if log is None else log
    rows = [(*log, np.ones(NUM_STEPS, bool))] + [tuple(o) for o in others]
    field = lambda k: jnp.asarray(np.stack([np.asarray(r[k], float) for r in rows]))
    n = len(rows)
    traj = Trajectory(x=field(0), y=field(1), z=jnp.zeros((n, NUM_STEPS)), yaw=field(2),
                      vel_x=field(3), vel_y=field(4), length=jnp.full((n, NUM_STEPS), 4.5),
                      width=jnp.full((n, NUM_STEPS), 2.0), height=jnp.ones((n, NUM_STEPS)),
                      valid=jnp.asarray(np.stack([np.asarray(r[5], bool) for r in rows])))
    sdc = SdcTrajectory(*(jnp.asarray(a, jnp.float32) for a in sim),
                        valid=jnp.ones(NUM_STEPS, bool))
    return FinalState(sdc=sdc, log=traj, sdc_index=jnp.int32(0),
                      timestep=jnp.int32(NUM_STEPS - 1))


def values(state) -> dict[str, float]:
    return {k: float(v) for k, v in registry.episode_values(state, None).items()}


def test_straight_constant_speed_is_comfortable_with_full_progress():
    v = values(make_state(_poses_from_speed(np.full(NUM_STEPS, 10.0))))
    assert v["progress"] == pytest.approx(1.0, abs=1e-4)
    assert v["max_abs_lon_jerk"] < 1e-2 and v["max_abs_lon_accel"] < 1e-2
    assert v["max_abs_lat_accel"] < 1e-2 and v["max_abs_yaw_rate"] < 1e-4
    assert v["comfortable"] == 1.0 and v["kinematic_infeasible"] == 0.0
    assert v["min_ttc"] == pytest.approx(em.TTC_HORIZON) and v["ttc_compliant"] == 1.0


def test_hard_brake_violates_longitudinal_bound_and_loses_progress():
    speed = np.clip(10.0 - 5.0 * np.clip(T - 4.0, 0, None), 0, None)  # -5 m/s^2 from 4 s
    log = _poses_from_speed(np.full(NUM_STEPS, 10.0))
    v = values(make_state(_poses_from_speed(speed), log))
    assert v["max_abs_lon_accel"] == pytest.approx(5.0, abs=0.5)
    assert v["comfortable"] == 0.0  # -5 < -4.05 m/s^2
    assert v["kinematic_infeasible"] == 0.0  # below 6 m/s^2
    # travelled 30 + 10 = 40 m of the log's 80 m from step 10
    assert v["progress"] == pytest.approx(40.0 / 80.0, abs=0.02)
    harder = np.clip(10.0 - 9.0 * np.clip(T - 4.0, 0, None), 0, None)
    assert values(make_state(_poses_from_speed(harder), log))["kinematic_infeasible"] == 1.0


def test_sharp_turns_violate_lateral_and_curvature_limits():
    fast = values(make_state(_poses_from_speed(np.full(NUM_STEPS, 10.0),
                                               np.full(NUM_STEPS, 1.0))))  # radius 10 m
    assert fast["max_abs_lat_accel"] == pytest.approx(10.0, rel=0.05)
    assert fast["max_abs_yaw_rate"] == pytest.approx(1.0, rel=0.02)
    assert fast["comfortable"] == 0.0 and fast["kinematic_infeasible"] == 1.0  # 10 m/s^2
    slow = values(make_state(_poses_from_speed(np.full(NUM_STEPS, 3.0),
                                               np.full(NUM_STEPS, 1.2))))  # curvature 0.4/m
    assert slow["max_abs_lat_accel"] < em.LAT_ACCEL_MAX  # 3.6 m/s^2: comfortable laterally
    assert slow["kinematic_infeasible"] == 1.0  # curvature 0.4 > 0.3 1/m
    gentle = values(make_state(_poses_from_speed(np.full(NUM_STEPS, 8.0),
                                                 np.full(NUM_STEPS, 0.2))))  # 1.6 m/s^2
    assert gentle["comfortable"] == 1.0 and gentle["kinematic_infeasible"] == 0.0


def _oncoming(ttc: float, lateral: float = 0.0, step: int = CURRENT_INDEX + 1):
    """A car driving at -10 m/s towards the SDC (10 m/s), visible at ``step`` only, placed so
    the two 4.5 m boxes touch after ``ttc`` s."""
    sdc_x = 10.0 * step * DT
    x0 = sdc_x + 4.5 + 20.0 * ttc
    valid = np.zeros(NUM_STEPS, bool)
    valid[step] = True
    x = x0 - 10.0 * (T - step * DT)
    return (x, np.full(NUM_STEPS, lateral), np.full(NUM_STEPS, np.pi),
            np.full(NUM_STEPS, -10.0), np.zeros(NUM_STEPS), valid)


def test_time_to_collision_of_two_boxes_closing_head_on():
    ego = _poses_from_speed(np.full(NUM_STEPS, 10.0))
    close = values(make_state(ego, others=[_oncoming(0.45)]))
    assert close["min_ttc"] == pytest.approx(0.5, abs=1e-4)  # first 0.1 s step with overlap
    assert close["ttc_compliant"] == 0.0
    far = values(make_state(ego, others=[_oncoming(2.05)]))
    assert far["min_ttc"] == pytest.approx(2.1, abs=1e-4) and far["ttc_compliant"] == 1.0
    beside = values(make_state(ego, others=[_oncoming(0.45, lateral=3.0)]))
    assert beside["min_ttc"] == pytest.approx(em.TTC_HORIZON) and beside["ttc_compliant"] == 1.0
    stopped = _poses_from_speed(np.zeros(NUM_STEPS))  # a stopped SDC has no TTC of its own
    assert values(make_state(stopped, others=[_oncoming(0.45)]))["ttc_compliant"] == 1.0


def test_pdm_score_combines_the_columns():
    row = dict(overlap=0.0, offroad=0.0, progress=1.0, ttc_compliant=1.0, comfortable=1.0)
    assert registry.pdm_score(row) == pytest.approx(1.0)
    assert registry.pdm_score({**row, "comfortable": 0.0}) == pytest.approx(10 / 12)
    assert registry.pdm_score({**row, "progress": 0.5}) == pytest.approx(9.5 / 12)
    assert registry.pdm_score({**row, "overlap": 1.0}) == 0.0
    assert registry.pdm_score({**row, "offroad": 1.0}) == 0.0


@pytest.fixture(scope="module")
def real_scene():
    if not SAMPLE.exists():
        pytest.skip(f"real WOMD sample not found at {SAMPLE}")
    from igdrivsim.data import Capacities, load_scenario, stack_scenarios
    from igdrivsim.simulator import SimParams

    sc = load_scenario(SAMPLE, caps=Capacities(max_objects=16, max_roadgraph_points=20_000))
    return stack_scenarios([sc, sc, sc]), SimParams()


@pytest.fixture(scope="module")
def real_frames(real_scene):
    scenarios, params = real_scene
    return rollout.reference_frames(scenarios, params, batch_size=2)[1]


def test_discretised_expert_on_real_womd_progresses_comfortably(real_frames):
    expert = real_frames[real_frames.method == "expert"]
    assert list(real_frames.columns) == list(SCENARIO_COLUMNS)
    assert (expert.progress > 0.98).all() and (expert.making_progress == 1.0).all()
    assert (expert.comfortable == 1.0).all() and (expert.kinematic_infeasible == 0.0).all()
    assert (expert.ttc_compliant == 1.0).all()
    assert (expert.pdm_score > 0.99).all()
    cv = real_frames[real_frames.method == "constant_velocity"]
    assert (cv.progress < expert.progress.min()).all()  # the log speeds up: CV falls behind


def test_registry_is_the_only_place_a_metric_is_named():
    keys = registry.columns()
    assert SCENARIO_COLUMNS == PER_SCENARIO_COLUMNS + keys  # Table I's first, unchanged
    quoted = re.compile("|".join(rf"[\"']{re.escape(k)}[\"']" for k in keys))
    for path in PACKAGE.rglob("*.py"):
        if path.name == "registry.py":
            continue
        found = quoted.findall(path.read_text())
        assert not found, f"{path} names registry metrics {found}: use the registry"


def test_a_registered_metric_reaches_csv_table_and_figure(monkeypatch, tmp_path):
    extra = registry.ScenarioMetric("final_speed", "final speed", "m/s", 1.0, True, "test",
                                    episode=lambda s, p: jnp.hypot(s.sdc.vel_x[-1],
                                                                   s.sdc.vel_y[-1]))
    monkeypatch.setattr(registry, "REGISTRY", [*registry.REGISTRY])
    registry.register(extra)
    with pytest.raises(ValueError):
        registry.register(extra)
    state = make_state(_poses_from_speed(np.full(NUM_STEPS, 10.0)))
    assert float(registry.episode_values(state, None)["final_speed"]) == pytest.approx(10.0)
    valid = np.ones((1, 2, 3), bool)
    zeros = np.zeros((1, 2, 3))
    scenario = {k: np.full((1, 2), 0.5) for k in registry.episode_keys()}
    out = rollout.StepOutputs(zeros, zeros, zeros, valid, scenario)
    _, per_scenario = rollout.tidy_frames(out, ["a", "b"], "full", "bc", [0])
    assert list(per_scenario.columns)[-1] == "final_speed"
    assert per_scenario.pdm_score.tolist() == pytest.approx([(2.5 + 2.5 + 1.0) / 12] * 2)
    frame = pd.concat([per_scenario.assign(seed=s, method=m) for s in (0, 1)
                       for m in ("bc", "bc_rl")])
    summary = aggregate.summarize(frame, metrics=registry.metrics())
    md = tables.supplementary_markdown(summary, registry.metrics())
    tex = tables.supplementary_latex(summary, registry.metrics())
    for m in registry.metrics():
        assert m.label.replace("|", r"\|") in md and m.source in md
    assert all(line.count("|") - line.count(r"\|") == 9 for line in md.splitlines()
               if line.startswith("| max") and "| BC" in line)  # escaped: 8 cells
    assert "final speed" in tex and r"\label{tab:supplementary}" in tex
    fig = figures.supplementary_figure(aggregate.seed_means(frame, registry.metrics()),
                                       registry.metrics())
    titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
    assert titles == [f"{m.label} {'↑' if m.higher_is_better else '↓'}"
                      for m in registry.metrics() if m.figure]


def test_report_writes_supplementary_outputs_also_for_old_csvs(tmp_path):
    from igdrivsim.report.build import build_report

    rows = []
    for method in ("bc", "bc_rl"):
        for seed in (0, 1):
            for i in range(4):
                rows.append(dict(setting="full", method=method, seed=seed,
                                 scenario_id=f"s{i}", max_log_divergence=1.0 + i, overlap=0.0,
                                 offroad=0.0, log_divergence=0.5, overlap_steps=0.0,
                                 offroad_steps=0.0))
    old = pd.DataFrame(rows)[list(PER_SCENARIO_COLUMNS)]  # written before the registry
    new = old.assign(setting="circular_r4", **{k: 0.75 for k in registry.columns()})
    (tmp_path / "ev" / "a").mkdir(parents=True)
    old.to_csv(tmp_path / "ev" / "per_scenario.csv", index=False)
    new.to_csv(tmp_path / "ev" / "a" / "per_scenario.csv", index=False)
    written = build_report([tmp_path / "ev"], tmp_path / "paper", run_dirs=[])
    names = {p.name for p in written}
    assert {"supplementary_metrics.md", "supplementary_metrics.tex",
            "fig5_supplementary.pdf", "fig5_supplementary.png"} <= names
    md = (tmp_path / "paper" / "tables" / "supplementary_metrics.md").read_text()
    line = next(r for r in md.splitlines() if r.startswith("| progress vs log") and "| BC |" in r)
    cells = [c.strip() for c in line.strip("|").split("|")][2:]
    assert cells[0] == "--" and cells[2].startswith("0.75")  # full: old CSV; circ r=4: new
    table1 = (tmp_path / "paper" / "tables" / "table1.md").read_text()
    assert "progress" not in table1  # Table I is unchanged


def test_episode_metrics_jit_and_vmap():
    states = [make_state(_poses_from_speed(np.full(NUM_STEPS, s))) for s in (5.0, 10.0)]
    batched = jax.tree.map(lambda *a: jnp.stack(a), *states)
    out = jax.jit(jax.vmap(lambda s: registry.episode_values(s, None)))(batched)
    assert out["progress"].shape == (2,) and np.allclose(out["comfortable"], 1.0)


def test_evaluate_policy_with_episode_metrics_keeps_per_step_shapes(real_scene):
    from igdrivsim.observation import ObservationConfig
    from igdrivsim.policy.act import example_observation
    from igdrivsim.policy.closed_loop import evaluate_policy
    from igdrivsim.policy.network import POOLED_NETWORK, PolicyConfig, init_params_per_seed

    scenarios, params = real_scene
    tiny = PolicyConfig(**POOLED_NETWORK, object_hidden=(8,), point_hidden=(8,),
                    roadgraph_hidden=(8,),
                        trunk_hidden=(8,), gru_hidden=8, actor_hidden=(8,), value_hidden=(8,))
    obs_config = ObservationConfig(4, 16)
    seeds = init_params_per_seed(tiny, jax.random.split(jax.random.key(0), 2),
                                 example_observation(obs_config))
    kwargs = dict(policy_config=tiny, obs_config=obs_config, params=params, batch_size=2)
    one = jax.tree.map(lambda x: x[None], seeds)
    plain = evaluate_policy(one, scenarios, setting=["full"], **kwargs)
    single = evaluate_policy(one, scenarios, setting=["full"],
                             episode_metrics=registry.episode_values, **kwargs)
    assert plain.scenario is None and plain.log_divergence.shape == (1, 2, 3, 80)
    assert single.log_divergence.shape == (1, 2, 3, 80)
    np.testing.assert_array_equal(plain.log_divergence, single.log_divergence)
    assert set(single.scenario) == set(registry.episode_keys())
    assert all(v.shape == (1, 2, 3) for v in single.scenario.values())
    both = jax.tree.map(lambda x: jnp.stack([x, x]), seeds)
    grouped = evaluate_policy(both, scenarios, setting=["full", "circular_r4"],
                              episode_metrics=registry.episode_values, **kwargs)
    assert grouped.log_divergence.shape == (2, 2, 3, 80)
    assert all(v.shape == (2, 2, 3) for v in grouped.scenario.values())
    np.testing.assert_allclose(grouped.scenario["progress"][0], single.scenario["progress"][0])
    _, frame = rollout.tidy_frames(grouped.map(lambda a: a[1]), ["a", "b", "c"],
                                   "circular_r4", "bc", [0, 1])
    assert frame[list(registry.columns())].notna().all().all()
