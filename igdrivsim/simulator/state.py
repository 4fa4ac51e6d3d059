"""Simulator state and the pure ``reset`` / ``step`` transitions (Waymax conventions).

Functions broadcast over leading batch dimensions ``...`` and ``jit``/``vmap``; pass
:class:`SimParams` as a static argument.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    DT,
    NUM_STEPS,
    ObjectMetadata,
    Roadgraph,
    Scenario,
    TrafficLights,
    Trajectory,
    decode_scenario_id,
)
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.simulator import agents as sim_agents
from igdrivsim.simulator import dynamics
from igdrivsim.simulator.roadgraph import RoadEdges, select_road_edges


@dataclass(frozen=True)
class SimParams:
    """Simulator settings (hashable: a static ``jit`` argument).

    ``edge_capacity``: slots for the offroad metric's road-edge points (a larger map keeps the
    nearest to the SDC at step 10). ``offroad_method``: ``"point"`` (Waymax's nearest-point
    rule) or ``"segment"`` (distance to edge segments; no false offroad at convex corners).
    ``roadgraph_stride``: the observable map keeps every k-th point of each polyline
    (:func:`thin_roadgraph`). ``agents``: ``"log"`` (replay, the paper's) or ``"idm"`` (reactive
    IDM vehicles on their logged paths) with ``idm`` their parameters.
    """

    dynamics: str = "delta_local"
    num_controlled_steps: int = NUM_STEPS - 1 - CURRENT_INDEX  # 80
    edge_capacity: int = 8192
    offroad_method: str = "point"
    roadgraph_stride: int = 1
    agents: str = "log"
    idm: sim_agents.IdmParams = sim_agents.IdmParams()

    def __post_init__(self):
        if self.agents not in sim_agents.AGENTS:
            raise ConfigError(f"sim agents must be one of {', '.join(sim_agents.AGENTS)}, "
                              f"got {self.agents!r}")
        if self.dynamics not in dynamics.DYNAMICS:
            raise ConfigError(f"SimParams.dynamics must be one of {sorted(dynamics.DYNAMICS)}, "
                              f"got {self.dynamics!r}")
        if self.offroad_method not in ("point", "segment"):
            raise ConfigError("SimParams.offroad_method must be 'point' or 'segment', "
                              f"got {self.offroad_method!r}")
        if not 1 <= self.num_controlled_steps <= NUM_STEPS - 1 - CURRENT_INDEX:
            raise ConfigError("SimParams.num_controlled_steps must be in 1..80, "
                              f"got {self.num_controlled_steps}")
        for name in ("edge_capacity", "roadgraph_stride"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"SimParams.{name} must be positive, got {getattr(self, name)}")


@struct.dataclass
class SdcTrajectory:
    """The simulated SDC, ``[..., T]`` per field."""

    x: jax.Array
    y: jax.Array
    yaw: jax.Array
    vel_x: jax.Array
    vel_y: jax.Array
    valid: jax.Array


@struct.dataclass
class ObjectState:
    """Every object at one step, ``[..., O]`` per field (SDC at its simulated pose)."""

    x: jax.Array
    y: jax.Array
    yaw: jax.Array
    vel_x: jax.Array
    vel_y: jax.Array
    length: jax.Array
    width: jax.Array
    valid: jax.Array


@struct.dataclass
class SimState:
    """``log`` ``[..., O, T]`` (T = 91), ``metadata`` ``[..., O]``, ``roadgraph`` (the observable
    map, thinned by ``roadgraph_stride``), ``road_edges`` (the offroad metric's road-edge points
    at full resolution), ``traffic_lights`` ``[..., L, T]``, ``scenario_id`` ``uint8[..., 32]``,
    ``sdc`` (the *simulated* SDC ``[..., T]``, the log for t <= 10, invalid after ``timestep``),
    ``sdc_index`` and ``timestep`` ``int32[...]`` (10 after reset)."""

    log: Trajectory
    metadata: ObjectMetadata
    roadgraph: Roadgraph
    road_edges: RoadEdges
    traffic_lights: TrafficLights
    scenario_id: jax.Array
    sdc: SdcTrajectory
    sdc_index: jax.Array
    timestep: jax.Array
    agents: sim_agents.AgentState | None = None  # every object simulated, under "idm" agents


def _take(a, t):
    """``a[..., t]`` for a per-batch index ``t [...]`` (a: ``[..., T]`` or ``[..., O, T]``)."""
    t = jnp.asarray(t)
    idx = t.reshape(t.shape + (1,) * (a.ndim - t.ndim))
    return jnp.take_along_axis(a, idx, axis=-1)[..., 0]


def _row(a, i):
    """``a[..., i, :]`` for a per-batch object index ``i [...]`` (a: ``[..., O, T]``)."""
    idx = jnp.asarray(i)[..., None, None]
    return jnp.take_along_axis(a, idx, axis=-2)[..., 0, :]


def vmap_batch(fn, n: int):
    """``fn`` of one example mapped over ``n`` leading batch dims (0: ``fn`` itself)."""
    for _ in range(n):
        fn = jax.vmap(fn)
    return fn


def check_scenario(scenario: Scenario) -> None:
    """Host-side check that each scenario of a batch has 91 steps and exactly one SDC, valid at
    step 10 (a :class:`DataError` naming the scenario)."""
    is_sdc = np.asarray(scenario.metadata.is_sdc)
    steps = np.shape(scenario.trajectory.x)[-1]
    if steps != NUM_STEPS:
        raise DataError(f"trajectories have {steps} steps, the simulator needs {NUM_STEPS}")
    count = is_sdc.sum(axis=-1)
    sdc_valid = (np.asarray(scenario.trajectory.valid)[..., CURRENT_INDEX] & is_sdc).any(axis=-1)
    ids = np.asarray(scenario.scenario_id).reshape(-1, np.shape(scenario.scenario_id)[-1])
    for flat, (n, ok) in enumerate(zip(count.reshape(-1), sdc_valid.reshape(-1), strict=True)):
        where = f"scenario {decode_scenario_id(ids[flat])!r} (batch index {flat})"
        if n != 1:
            raise DataError(f"{where}: needs exactly one SDC (is_sdc), found {int(n)}")
        if not ok:
            raise DataError(f"{where}: the SDC is invalid at the current step {CURRENT_INDEX}")


def thin_roadgraph(rg: Roadgraph, stride: int, ref_xy: jax.Array) -> Roadgraph:
    """The observable map of ONE scenario: every ``stride``-th point of each polyline and its
    last, compacted to the ``ceil(R / stride)`` nearest to ``ref_xy`` (the SDC at step 10)."""
    if stride == 1:
        return rg
    ids = jnp.asarray(rg.id)
    n = ids.shape[-1]
    i = jnp.arange(n)
    first = jnp.concatenate([jnp.ones((1,), bool), ids[1:] != ids[:-1]])
    last = jnp.concatenate([ids[:-1] != ids[1:], jnp.ones((1,), bool)])
    run_start = jax.lax.cummax(jnp.where(first, i, 0))
    keep = jnp.asarray(rg.valid, bool) & (((i - run_start) % stride == 0) | last)
    d2 = jnp.sum((jnp.asarray(rg.xyz)[:, :2] - ref_xy) ** 2, axis=-1)
    _, idx = jax.lax.top_k(jnp.where(keep, -d2, -jnp.inf), -(-n // stride))
    idx = jnp.sort(idx)
    rg = jax.tree.map(lambda a: jnp.take(jnp.asarray(a), idx, axis=0), rg)
    return rg.replace(valid=jnp.take(keep, idx))


def reset(scenario: Scenario, params: SimParams = SimParams()) -> SimState:
    """The state at timestep 10 (warm-up replayed from the log); concrete inputs are checked."""
    if not any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(scenario)):
        check_scenario(scenario)
    sc = jax.tree.map(jnp.asarray, scenario)
    traj = sc.trajectory
    sdc_index = jnp.argmax(sc.metadata.is_sdc, axis=-1).astype(jnp.int32)
    row = jax.tree.map(lambda a: _row(a, sdc_index), traj)  # the SDC's log
    ref = jnp.stack([row.x[..., CURRENT_INDEX], row.y[..., CURRENT_INDEX]], -1)
    road_edges = vmap_batch(
        lambda rg, r: select_road_edges(rg, r, edge_capacity=params.edge_capacity),
        sdc_index.ndim)(sc.roadgraph, ref)
    roadgraph = vmap_batch(lambda rg, r: thin_roadgraph(rg, params.roadgraph_stride, r),
                            sdc_index.ndim)(sc.roadgraph, ref)
    sdc = SdcTrajectory(x=row.x, y=row.y, yaw=row.yaw, vel_x=row.vel_x, vel_y=row.vel_y,
                        valid=row.valid & (jnp.arange(traj.x.shape[-1]) <= CURRENT_INDEX))
    agents = None
    if params.agents == "idm":
        agents = vmap_batch(lambda lg, md, i: sim_agents.init_agents(lg, md, i, params.idm),
                            sdc_index.ndim)(traj, sc.metadata, sdc_index)
    return SimState(
        log=traj, metadata=sc.metadata, roadgraph=roadgraph, road_edges=road_edges,
        traffic_lights=sc.traffic_lights, scenario_id=sc.scenario_id, sdc=sdc, agents=agents,
        sdc_index=sdc_index, timestep=jnp.full(sdc_index.shape, CURRENT_INDEX, jnp.int32))


def sdc_pose(state: SimState):
    """The simulated SDC at the current step: ``(x, y, yaw, valid)``, each ``[...]``."""
    s = state.sdc
    return tuple(_take(a, state.timestep) for a in (s.x, s.y, s.yaw, s.valid))


def sdc_yaw_rate(state: SimState):
    """The SDC's heading change over the last step in rad/s (its odometry; 0 if unknown)."""
    t, s = state.timestep, state.sdc
    prev = jnp.maximum(t - 1, 0)
    ok = (t > 0) & _take(s.valid, t) & _take(s.valid, prev)
    turn = dynamics.wrap_angle(_take(s.yaw, t) - _take(s.yaw, prev))
    return jnp.where(ok, turn / DT, 0.0).astype(jnp.float32)


def log_sdc_at(state: SimState, t):
    """The logged SDC at step ``t [...]``: ``(x, y, yaw, valid)``."""
    lg = state.log
    return tuple(_take(_row(a, state.sdc_index), t) for a in (lg.x, lg.y, lg.yaw, lg.valid))


def log_sdc_row(state: SimState) -> Trajectory:
    """The SDC's logged trajectory ``[..., T]`` (every :class:`Trajectory` field)."""
    return jax.tree.map(lambda a: _row(a, state.sdc_index), state.log)


def step(state: SimState, action, params: SimParams = SimParams()) -> SimState:
    """Advance one step: the SDC applies ``action`` ``[..., 3]`` (a concrete non-finite one is
    a :class:`DataError`), the other objects replay their log or move as IDM agents; the SDC's
    validity at ``t + 1`` is its logged one; timestep 90 stays 90."""
    if not isinstance(action, jax.core.Tracer):
        dynamics.validate_actions(action)
    if (state.agents is None) != (params.agents == "log"):
        raise ConfigError(f"the state was reset for other sim agents than {params.agents!r}: "
                          "reset and step with the same SimParams")
    agents = state.agents
    if agents is not None:
        agents = vmap_batch(lambda a, ob, lt, t: sim_agents.step_agents(a, ob, lt, t, params.idm),
                            state.timestep.ndim)(agents, current_objects(state),
                                                 state.traffic_lights, state.timestep)
    forward, _ = dynamics.DYNAMICS[params.dynamics]
    x, y, yaw, _ = sdc_pose(state)
    nx, ny, nyaw, vx, vy = forward(x, y, yaw, jnp.asarray(action, jnp.float32))
    t1 = jnp.minimum(state.timestep + 1, NUM_STEPS - 1)
    log_valid1 = log_sdc_at(state, t1)[3]
    at = jnp.arange(state.sdc.x.shape[-1]) == t1[..., None]

    def put(old, new):
        return jnp.where(at, jnp.asarray(new, old.dtype)[..., None], old)

    s = state.sdc
    sdc = SdcTrajectory(x=put(s.x, nx), y=put(s.y, ny), yaw=put(s.yaw, nyaw),
                        vel_x=put(s.vel_x, vx), vel_y=put(s.vel_y, vy),
                        valid=put(s.valid, log_valid1))
    return state.replace(sdc=sdc, timestep=t1, agents=agents)


def current_objects(state: SimState) -> ObjectState:
    """All objects at the current step, ``[..., O]``; the SDC row holds its simulated state."""
    t = state.timestep
    lg = object_trajectory(state)
    is_sdc = jnp.arange(lg.x.shape[-2]) == state.sdc_index[..., None]
    s = state.sdc

    def pick(log_a, sim_a):
        cur = _take(log_a, t)
        return cur if sim_a is None else jnp.where(is_sdc, _take(sim_a, t)[..., None], cur)

    return ObjectState(x=pick(lg.x, s.x), y=pick(lg.y, s.y), yaw=pick(lg.yaw, s.yaw),
                       vel_x=pick(lg.vel_x, s.vel_x), vel_y=pick(lg.vel_y, s.vel_y),
                       length=pick(lg.length, None), width=pick(lg.width, None),
                       valid=pick(lg.valid, s.valid))


def object_trajectory(state: SimState) -> Trajectory:
    """Every object's ``[..., O, T]`` trajectory as simulated by the sim agents (the log under
    ``"log"`` agents); the SDC row is its log."""
    a = state.agents
    if a is None:
        return state.log
    return state.log.replace(x=a.x, y=a.y, yaw=a.yaw, vel_x=a.vel_x, vel_y=a.vel_y, valid=a.valid)

