"""Teacher-forced observation records: computed once per dataset, cached on disk, shared by
every run.

BC is trained on the logged episode: warm-up steps 0..9 replayed from the log, then the
discretised expert driving steps 10..89. :func:`compute_records` records what the ego sees along
it before any setting, with the expert's labels. The cache file is keyed by a hash of the data's
identity and of everything that shapes the recording (:func:`cache_key`).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
from dataclasses import asdict

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS
from igdrivsim.io import atomic_path
from igdrivsim.observation import ObservationConfig, ObservationRecord, get_setting, observe
from igdrivsim.observation.features import ROADGRAPH_GEOMETRY, roadgraph_kind
from igdrivsim.simulator import SimParams, SimState, dynamics, sdc_pose
from igdrivsim.simulator.rollout import Actor, expert_action, run_episode

FORMAT_VERSION = 4
EPISODE_STEPS = NUM_STEPS - 1  # 10 warm-up + 80 controlled observations per episode


def _record(state: SimState, rec: ObservationConfig):
    """Observation of one state under full observability at the superset capacities."""
    key = jax.random.key(0)  # full observability draws nothing
    obs = observe(state, get_setting("full"), key, key, rec)
    rg = obs.roadgraph
    kind = roadgraph_kind(rg).astype(jnp.int8)
    _, _, yaw, _ = sdc_pose(state)
    return (obs.objects, obs.objects_valid, rg[..., ROADGRAPH_GEOMETRY], kind, obs.roadgraph_valid,
            obs.sdc_speed, obs.sdc_yaw_rate, yaw)


def record_episode(state: SimState, sim: SimParams, rec: ObservationConfig) -> ObservationRecord:
    """The :class:`ObservationRecord` of ONE scenario at reset: warm-up (log) and
    expert-driven observations and labels."""
    warm = jax.vmap(lambda t: _record(state.replace(timestep=t), rec))(
        jnp.arange(CURRENT_INDEX))

    def teacher(s, carry, key):  # the discretised expert, recording what it sees
        del key
        idx = dynamics.discretize(expert_action(s, sim))
        return dynamics.undiscretize(idx), carry, (_record(s, rec), idx.astype(jnp.int16))

    _, tr = run_episode(state, Actor(step=teacher), jax.random.key(0), sim, metrics_fn=None)
    (drive, actions), valid = tr.extras, tr.valid
    fields = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), warm, drive)
    return ObservationRecord(*fields, actions=actions, action_valid=valid)


@functools.lru_cache(maxsize=4)
def _jit_episodes(sim: SimParams, rec: ObservationConfig):
    return jax.jit(jax.vmap(lambda s: record_episode(s, sim, rec)))


def compute_records(states: SimState, sim: SimParams, rec: ObservationConfig,
                    chunk: int = 32, progress: bool = False) -> ObservationRecord:
    """Teacher-forced records of host states ``[N]`` (chunks of ``chunk``), as NumPy."""
    n = int(np.shape(states.timestep)[0])
    fn = _jit_episodes(sim, rec)
    parts = []
    with tqdm(total=n, desc="teacher-forced observations", unit="scn", dynamic_ncols=True,
              disable=not progress) as bar:
        for start in range(0, n, chunk):
            idx = np.minimum(np.arange(start, start + chunk), n - 1)
            size = min(chunk, n - start)
            part = jax.device_get(fn(jax.tree.map(lambda x, i=idx: x[i], states)))
            parts.append(jax.tree.map(lambda x, k=size: np.asarray(x)[:k], part))
            bar.update(size)
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


def cache_key(identity: str, **shape) -> str:
    payload = json.dumps({"data": identity, "format": FORMAT_VERSION, **shape}, sort_keys=True,
                         default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:20]


def load_or_compute(cache_dir: str | None, key: str, compute) -> ObservationRecord:
    """The cached records ``cache_dir/teacher-<key>.npz``, computed and saved if absent (no
    ``cache_dir``: not saved); processes sharing the cache wait on a lock for the first."""
    import fcntl  # optional: Unix only (file locks)

    path = os.path.join(cache_dir, f"teacher-{key}.npz") if cache_dir else None
    with contextlib.ExitStack() as stack:
        if path:
            os.makedirs(cache_dir, exist_ok=True)
            lock = stack.enter_context(open(path + ".lock", "a"))
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes (or we die)
        if path and os.path.isfile(path):
            with np.load(path) as z:
                return ObservationRecord(**{k: z[k] for k in z.files})
        records = compute()
        if path:
            with atomic_path(path, "wb") as f:
                np.savez(f, **{k: np.asarray(v) for k, v in asdict(records).items()})
        return records
