"""Teacher-forced observations: computed once per dataset, cached on disk, shared by every run.

BC is trained on the logged (expert-driven) episode: the warm-up steps 0..9 replayed from the
log, then the discretised expert driving steps 10..89. That episode is deterministic, so what
the ego sees along it *before* the partial-observability model is the same for every setting,
seed and method. :func:`compute_teacher` records it once per scenario, in the TRUE ego frame,
with more than the observation's capacities: every other object slot (``K``) and the ``M =
4 N`` nearest roadgraph points. :func:`teacher_observation` then applies a setting (as data,
:class:`~igdrivsim.observation.ObservationParams`) on the fly:

1. the believed pose (Gaussian position noise) shifts every point by the same offset, and the
   ``N`` nearest points / ``n`` nearest objects are re-selected around the believed position
   from the cached superset (without noise the cached order is taken as is);
2. the setting's hiding (fields of view, masking) with the same keys as the online
   observation (episode key per scenario, step key ``fold_in(episode key, t)``).

Without noise this equals :func:`igdrivsim.observation.observe` exactly; with noise it does
while the ``N`` nearest points around the believed position are among the ``4 N`` nearest
around the true one, i.e. while the offset is below the radius of the ``N`` nearest (tens of
metres for the observation sizes in use, against an offset of a few metres).

The cache file is keyed by a hash of the data's identity (the manifest's bytes, or the files'
names, sizes and modification times) and of everything that shapes the recording
(capacities, simulator parameters, this module's format version): change either and it is
recomputed. Files are written atomically.
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
from flax import struct
from tqdm.auto import tqdm

from igdrivsim.data import expand_paths
from igdrivsim.data.manifest import read_manifest
from igdrivsim.data.scenario import CURRENT_INDEX, NUM_STEPS, RG_NUM_TYPES
from igdrivsim.errors import DataError
from igdrivsim.io import atomic_path
from igdrivsim.observation import (
    Observation,
    ObservationConfig,
    get_setting,
    observe,
    perceive_pose,
)
from igdrivsim.observation.features import POSITION_SCALE, nearest, rotate_to_frame
from igdrivsim.observation.models import apply_setting
from igdrivsim.simulator import SimParams, SimState, dynamics, sdc_pose
from igdrivsim.simulator.expert import expert_action
from igdrivsim.simulator.rollout import Actor, run_episode

FORMAT_VERSION = 4
EPISODE_STEPS = NUM_STEPS - 1  # 10 warm-up + 80 controlled observations per episode


@struct.dataclass
class TeacherSteps:
    """One scenario's teacher-forced episode (leading axes ``[..., T=90]``), true ego frame.

    Observation fields hold the features of :mod:`igdrivsim.observation.features` (positions
    divided by 100) for the ``K`` object slots and ``M`` roadgraph points nearest the true pose,
    nearest first; ``actions``/``action_valid`` are the discretised expert's labels of the 80
    controlled steps (index ``t - 10``).
    """

    objects: jax.Array  # f32[..., T, K, 6]
    objects_valid: jax.Array  # bool[..., T, K]
    roadgraph: jax.Array  # f32[..., T, M, 4]: x, y, dir_x, dir_y
    roadgraph_type: jax.Array  # int8[..., T, M]
    roadgraph_valid: jax.Array  # bool[..., T, M]
    sdc_speed: jax.Array  # f32[..., T, 1]
    sdc_yaw_rate: jax.Array  # f32[..., T, 1]
    sdc_yaw: jax.Array  # f32[..., T]
    actions: jax.Array  # int16[..., 80, 3]
    action_valid: jax.Array  # bool[..., 80]


def superset_config(obs: ObservationConfig, max_objects: int) -> ObservationConfig:
    """What is recorded: every other object slot and four times the observed roadgraph points
    (the ``N`` nearest around a believed position ``e`` metres off are among the ``4 N``
    nearest around the true one while ``e`` is below the radius of the ``N`` nearest)."""
    return ObservationConfig(max(obs.num_objects, max_objects - 1), 4 * obs.num_roadgraph_points)


def _record(state: SimState, rec: ObservationConfig):
    """Observation of one state under full observability at the superset capacities."""
    key = jax.random.key(0)  # full observability draws nothing
    obs = observe(state, get_setting("full"), key, key, rec)
    rg = obs.roadgraph
    kind = jnp.argmax(rg[..., 4:-1], axis=-1).astype(jnp.int8)
    _, _, yaw, _ = sdc_pose(state)
    return (obs.objects, obs.objects_valid, rg[..., :4], kind, obs.roadgraph_valid,
            obs.sdc_speed, obs.sdc_yaw_rate, yaw)


def record_episode(state: SimState, sim: SimParams, rec: ObservationConfig) -> TeacherSteps:
    """Warm-up (log) and expert-driven observations and labels of ONE scenario at reset
    (the record of :class:`TeacherSteps`)."""
    warm = jax.vmap(lambda t: _record(state.replace(timestep=t), rec))(
        jnp.arange(CURRENT_INDEX))

    def teacher(s, carry, key):  # the discretised expert, recording what it sees
        del key
        idx = dynamics.discretize(expert_action(s, sim))
        return dynamics.undiscretize(idx), carry, (_record(s, rec), idx.astype(jnp.int16))

    _, tr = run_episode(state, Actor(step=teacher), jax.random.key(0), sim, metrics_fn=None)
    (drive, actions), valid = tr.extras, tr.valid
    fields = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), warm, drive)
    return TeacherSteps(*fields, actions=actions, action_valid=valid)


@functools.lru_cache(maxsize=4)
def _jit_episodes(sim: SimParams, rec: ObservationConfig):
    return jax.jit(jax.vmap(lambda s: record_episode(s, sim, rec)))


def compute_teacher(states: SimState, sim: SimParams, rec: ObservationConfig,
                    chunk: int = 32, progress: bool = False) -> TeacherSteps:
    """Teacher-forced records of host states ``[N]`` (chunks of ``chunk``), as NumPy."""
    n = int(np.shape(states.timestep)[0])
    fn = _jit_episodes(sim, rec)
    bar = None
    if progress:
        bar = tqdm(total=n, desc="teacher-forced observations", unit="scn", dynamic_ncols=True)
    parts = []
    for start in range(0, n, chunk):
        idx = np.minimum(np.arange(start, start + chunk), n - 1)
        size = min(chunk, n - start)
        part = jax.device_get(fn(jax.tree.map(lambda x, i=idx: x[i], states)))
        parts.append(jax.tree.map(lambda x, k=size: np.asarray(x)[:k], part))
        if bar is not None:
            bar.update(size)
    if bar is not None:
        bar.close()
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


def data_identity(data) -> str:
    """A string that changes when the data changes: the manifest's bytes or the files' stats."""
    path = os.fspath(data)
    manifest = os.path.join(path, "manifest.jsonl") if os.path.isdir(path) else None
    h = hashlib.sha256()
    if manifest and os.path.isfile(manifest):
        with open(manifest, "rb") as f:
            h.update(f.read())
        # the files the manifest points at (relative to its folder; checked line by line)
        files = sorted({e["file"] for e in read_manifest(manifest, kept_only=False)})
    else:
        files = expand_paths(path)
    for name in files:
        if not os.path.isfile(name):
            raise DataError("the filter manifest points at a missing file", file=name)
        st = os.stat(name)
        h.update(f"{os.path.abspath(name)}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()


def cache_key(identity: str, **shape) -> str:
    payload = json.dumps({"data": identity, "format": FORMAT_VERSION, **shape}, sort_keys=True,
                         default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:20]


def load_or_compute(cache_dir: str | None, key: str, compute) -> TeacherSteps:
    """The cached records under ``cache_dir/teacher-<key>.npz``, computed and saved if absent
    (no ``cache_dir``: computed, not saved). Processes sharing the cache (the pipeline's
    parallel training parts) compute each record file once: the others wait on its lock."""
    import fcntl  # optional: Unix only (file locks)

    path = os.path.join(cache_dir, f"teacher-{key}.npz") if cache_dir else None
    with contextlib.ExitStack() as stack:
        if path:
            os.makedirs(cache_dir, exist_ok=True)
            lock = stack.enter_context(open(path + ".lock", "a"))
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes (or we die)
        if path and os.path.isfile(path):
            with np.load(path) as z:
                return TeacherSteps(**{k: z[k] for k in z.files})
        records = compute()
        if path:
            with atomic_path(path, "wb") as f:
                np.savez(f, **{k: np.asarray(v) for k, v in asdict(records).items()})
        return records


def teacher_observation(rec: TeacherSteps, t, setting, episode_key: jax.Array,
                        config: ObservationConfig) -> Observation:
    """The observation at step ``t`` of one recorded episode under ``setting`` (one example:
    ``rec`` fields ``[K, ...]`` / ``[M, ...]`` at that step; ``vmap`` over steps/examples)."""
    step_key = jax.random.fold_in(episode_key, t)
    yaw = rec.sdc_yaw
    zero = jnp.zeros((2,), jnp.float32)
    offset, _ = perceive_pose(setting, zero, yaw, episode_key, step_key)
    dx, dy = rotate_to_frame(offset[0], offset[1], yaw)
    shift = jnp.stack([dx, dy]) / POSITION_SCALE
    moved = jnp.any(shift != 0)

    def pick(xy, valid, n):
        """The ``n`` nearest around the believed pose (the cached order when not moved)."""
        idx, ok = nearest(jnp.sum((xy - shift) ** 2, -1), valid, n)
        first = jnp.arange(n)
        return jnp.where(moved, idx, first), jnp.where(moved, ok, valid[:n])

    oi, ov = pick(rec.objects[:, :2], rec.objects_valid, config.num_objects)
    objects = rec.objects[oi].at[:, :2].add(-shift)
    objects = jnp.where(ov[:, None], objects, 0.0)
    ri, rv = pick(rec.roadgraph[:, :2], rec.roadgraph_valid, config.num_roadgraph_points)
    rg4 = rec.roadgraph[ri].at[:, :2].add(-shift)
    kind = rec.roadgraph_type[ri].astype(jnp.int32)
    onehot = jax.nn.one_hot(kind, RG_NUM_TYPES, dtype=jnp.float32)
    rg = jnp.concatenate([rg4, onehot, jnp.ones_like(rg4[:, :1])], -1)
    rg = jnp.where(rv[:, None], rg, 0.0)
    obs = Observation(objects=objects, objects_valid=ov, roadgraph=rg, roadgraph_valid=rv,
                      sdc_speed=rec.sdc_speed, sdc_yaw_rate=rec.sdc_yaw_rate)
    return apply_setting(setting, obs, episode_key, step_key)


def episode_observations(rec: TeacherSteps, setting, episode_key: jax.Array,
                         config: ObservationConfig) -> Observation:
    """All 90 observations of one recorded episode, ``[T, ...]``."""
    steps = jnp.arange(rec.sdc_yaw.shape[0])
    per_step = rec.replace(actions=None, action_valid=None)  # the labels have 80 steps, not 90
    return jax.vmap(lambda r, t: teacher_observation(r, t, setting, episode_key, config))(
        per_step, steps)
