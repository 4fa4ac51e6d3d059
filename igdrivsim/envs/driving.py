"""The driving task as a Gymnasium environment (id ``IGDrivSim/Driving-v0``) and as pure,
batched JAX functions (:func:`driving_functions`, which the class wraps).

One scenario per episode (``options={"index": i}`` or drawn from ``np_random``): the observation
under the setting from step 10, ``SimParams.num_controlled_steps`` steps, then truncation. Reward
``-1[overlap] - 1[offroad]``; ``info`` holds the step's metrics, and at the last step the
episode's Table I metrics. Observation: a ``Dict`` of the
:class:`~igdrivsim.observation.Observation` fields (masks ``int8``). Action: the expert's bins
``MultiDiscrete([257] * 3)``, or with ``continuous=True`` a ``Box`` of ``(dx, dy, dyaw)``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any, NamedTuple

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from gymnasium import spaces

from igdrivsim.data import Scenario
from igdrivsim.data.egos import check_egos, expand_egos
from igdrivsim.data.reader import unbatch
from igdrivsim.data.scenario import CURRENT_INDEX, DEFAULT_CAPS, Capacities, decode_scenario_id
from igdrivsim.data.source import open_scenarios
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.observation import Observation, ObservationConfig, get_setting, observe
from igdrivsim.observation.features import OBJECT_FEATURES, ROADGRAPH_FEATURES
from igdrivsim.simulator import (
    ACTION_HIGH,
    ACTION_LOW,
    NUM_LEVELS,
    SimParams,
    SimState,
    check_scenario,
    expert_discrete_action,
    reset,
    reward,
    step,
    step_metrics,
    undiscretize,
    validate_actions,
)

ENV_ID = "IGDrivSim/Driving-v0"
DEFAULT_PARAMS, DEFAULT_CONFIG = SimParams(), ObservationConfig()


@struct.dataclass
class EnvState:
    """The simulator state and the episode's observation key (fixed for the episode)."""

    sim: SimState
    episode_key: jax.Array  # uint32[..., 2] (jax.random.PRNGKey)


class DrivingFunctions(NamedTuple):
    """Jitted ``reset(scenario, key) -> (state, obs)``, ``step(state, action) -> (state, obs,
    reward, done, metrics)``, ``expert(state) -> int32[3]``, and their ``batch_*`` versions."""

    reset: Any
    step: Any
    expert: Any
    batch_reset: Any
    batch_step: Any
    batch_expert: Any


def _observe(state: EnvState, setting, config: ObservationConfig) -> Observation:
    step_key = jax.random.fold_in(state.episode_key, state.sim.timestep)
    return observe(state.sim, setting, state.episode_key, step_key, config)


@functools.cache
def driving_functions(setting: str = "full", params: SimParams = DEFAULT_PARAMS,
                      config: ObservationConfig = DEFAULT_CONFIG,
                      continuous: bool = False) -> DrivingFunctions:
    """The environment's pure functions for an observation ``setting`` (cached)."""
    obs_setting = get_setting(setting)
    last = CURRENT_INDEX + params.num_controlled_steps

    def reset_one(scenario: Scenario, key: jax.Array) -> tuple[EnvState, Observation]:
        state = EnvState(sim=reset(scenario, params), episode_key=key)
        return state, _observe(state, obs_setting, config)

    def step_one(state: EnvState, action: jax.Array):
        act = (jnp.asarray(action, jnp.float32) if continuous
               else undiscretize(jnp.asarray(action, jnp.int32)))
        sim = step(state.sim, act, params)
        metrics = step_metrics(sim, params)
        state = state.replace(sim=sim)
        return (state, _observe(state, obs_setting, config), reward(metrics),
                sim.timestep >= last, metrics)

    def expert_one(state: EnvState) -> jax.Array:
        return expert_discrete_action(state.sim, params)

    return DrivingFunctions(
        reset=jax.jit(reset_one), step=jax.jit(step_one), expert=jax.jit(expert_one),
        batch_reset=jax.jit(jax.vmap(reset_one)), batch_step=jax.jit(jax.vmap(step_one)),
        batch_expert=jax.jit(jax.vmap(expert_one)))


def _observation_space(config: ObservationConfig) -> spaces.Dict:
    box = lambda *shape: spaces.Box(-np.inf, np.inf, shape, np.float32)
    n_obj, n_rg = config.num_objects, config.num_roadgraph_points
    return spaces.Dict({
        "objects": box(n_obj, OBJECT_FEATURES),
        "objects_valid": spaces.MultiBinary(n_obj),
        "roadgraph": box(n_rg, ROADGRAPH_FEATURES),
        "roadgraph_valid": spaces.MultiBinary(n_rg),
        "sdc_speed": box(1),
        "sdc_yaw_rate": box(1),
    })


def _to_numpy(obs: Observation) -> dict[str, np.ndarray]:
    """The observation's fields as the space's NumPy arrays (the masks as ``int8``)."""
    obs = jax.device_get(obs)
    return {f.name: np.asarray(getattr(obs, f.name),
                               np.int8 if f.name.endswith("_valid") else np.float32)
            for f in dataclasses.fields(obs)}


def _load(data, caps: Capacities, max_scenarios: int | None, egos: str = "sdc"
          ) -> list[Scenario]:
    check_egos(egos)
    if isinstance(data, Scenario):
        data = [data]
    if isinstance(data, Sequence) and data and all(isinstance(s, Scenario) for s in data):
        scenarios = list(unbatch(data))
        if egos == "all":
            scenarios = [e for s in scenarios for e, _ in expand_egos(s)]
    else:
        scenarios = [rec.scenario for rec in open_scenarios(data, caps, egos=egos,
                                                            limit=max_scenarios or 0)]
    scenarios = scenarios[:max_scenarios]
    if not scenarios:
        raise DataError("no scenarios to drive in", file=str(data))
    for s in scenarios:
        check_scenario(s)
    return scenarios


class DrivingEnv(gym.Env):
    """Gymnasium wrapper of :func:`driving_functions`: one scenario per episode."""

    metadata = {"render_modes": []}

    def __init__(self, data, setting: str = "full", continuous: bool = False,
                 params: SimParams = DEFAULT_PARAMS, config: ObservationConfig = DEFAULT_CONFIG,
                 caps: Capacities = DEFAULT_CAPS, max_scenarios: int | None = None,
                 egos: str = "sdc"):
        """``data``: any data path (:func:`~igdrivsim.data.source.open_scenarios`) or
        :class:`Scenario` objects, all loaded (at most ``max_scenarios``)."""
        if not isinstance(setting, str):
            raise ConfigError(f"setting must be a preset name, got {setting!r}")
        self.setting = get_setting(setting).name
        self.continuous = continuous
        self.params, self.config = params, config
        self.scenarios = _load(data, caps, max_scenarios, egos)
        self.fns = driving_functions(self.setting, params, config, continuous)
        self.observation_space = _observation_space(config)
        self.action_space = (spaces.Box(np.asarray(ACTION_LOW, np.float32),
                                        np.asarray(ACTION_HIGH, np.float32), dtype=np.float32)
                             if continuous else spaces.MultiDiscrete([NUM_LEVELS] * 3))
        self.state: EnvState | None = None
        self.index = -1
        self._totals: dict[str, float] = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        index = (options or {}).get("index")
        if index is None:
            index = int(self.np_random.integers(len(self.scenarios)))
        if not 0 <= int(index) < len(self.scenarios):
            raise ConfigError(f"options['index'] must be in 0..{len(self.scenarios) - 1}, "
                              f"got {index}")
        self.index = int(index)
        key = jax.random.PRNGKey(int(self.np_random.integers(2**31)))
        self.state, obs = self.fns.reset(self.scenarios[self.index], key)
        self._totals = {"overlap_rate": 0.0, "offroad_rate": 0.0, "max_log_divergence": 0.0}
        return _to_numpy(obs), {"scenario_id": self._scenario_id(), "index": self.index,
                                "timestep": CURRENT_INDEX}

    def step(self, action):
        if self.state is None:
            raise ConfigError("call reset() before step()")
        action = np.asarray(action)
        if self.continuous:
            validate_actions(action.astype(np.float32))
        elif action.shape != (3,) or not np.all((action >= 0) & (action < NUM_LEVELS)):
            raise ConfigError(f"action must be 3 integers in 0..{NUM_LEVELS - 1}, got {action}")
        self.state, obs, rew, done, metrics = self.fns.step(self.state, action)
        m = jax.device_get(metrics)
        valid = bool(m.valid)
        info = {"overlap": bool(m.overlap), "offroad": bool(m.offroad),
                "log_divergence": float(m.log_divergence) if valid else 0.0, "valid": valid,
                "scenario_id": self._scenario_id(), "timestep": int(self.state.sim.timestep)}
        for key, name in (("overlap_rate", "overlap"), ("offroad_rate", "offroad"),
                          ("max_log_divergence", "log_divergence")):
            self._totals[key] = max(self._totals[key], float(info[name]))
        if done:
            info.update(self._totals)
        return _to_numpy(obs), float(rew), False, bool(done), info

    def expert_action(self) -> np.ndarray:
        """The discretised expert's action for the current state (``int64[3]``)."""
        if self.state is None:
            raise ConfigError("call reset() before expert_action()")
        return np.asarray(self.fns.expert(self.state), np.int64)

    def _scenario_id(self) -> str:
        return decode_scenario_id(self.scenarios[self.index].scenario_id)


def register() -> None:
    """Register ``IGDrivSim/Driving-v0`` with Gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="igdrivsim.envs.driving:DrivingEnv")


register()
