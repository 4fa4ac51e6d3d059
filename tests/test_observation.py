"""The SDC-frame observation and the partial-observability models, on constructed geometry."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest
from flax import struct

from igdrivsim.data.scenario import Roadgraph
from igdrivsim.errors import ConfigError
from igdrivsim.observation import (
    PAPER_SETTINGS,
    PRESETS,
    CircularFieldOfView,
    ConicFieldOfView,
    FunctionModel,
    GaussianPositionNoise,
    ObservationConfig,
    ObservationSetting,
    RandomMasking,
    get_setting,
    hide_objects,
    object_positions,
    observe_setting_arrays,
    roadgraph_positions,
)

CFG = ObservationConfig(num_objects=8, num_roadgraph_points=8)


@struct.dataclass
class Objs:
    x: jax.Array
    y: jax.Array
    yaw: jax.Array
    vel_x: jax.Array
    vel_y: jax.Array
    valid: jax.Array


def make_objects(xy, yaw=None, vel=None, valid=None) -> Objs:
    xy = np.asarray(xy, np.float32)
    n = len(xy)
    yaw = np.zeros(n, np.float32) if yaw is None else np.asarray(yaw, np.float32)
    vel = np.zeros((n, 2), np.float32) if vel is None else np.asarray(vel, np.float32)
    valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    return Objs(xy[:, 0], xy[:, 1], yaw, vel[:, 0], vel[:, 1], valid)


def make_roadgraph(xy, dirs=None, types=None, valid=None) -> Roadgraph:
    xy = np.asarray(xy, np.float32)
    n = len(xy)
    dirs = np.tile([[1.0, 0.0]], (n, 1)) if dirs is None else np.asarray(dirs, np.float32)
    return Roadgraph(
        xyz=np.concatenate([xy, np.zeros((n, 1), np.float32)], 1),
        dir=np.concatenate([dirs, np.zeros((n, 1), np.float32)], 1).astype(np.float32),
        type=np.full(n, 2, np.int32) if types is None else np.asarray(types, np.int32),
        id=np.zeros(n, np.int32),
        valid=np.ones(n, bool) if valid is None else np.asarray(valid, bool),
    )


# Shared compiled function (settings and config are static); NONE: no model, the plain features.
_obs = jax.jit(observe_setting_arrays, static_argnames=("setting", "config"))
NONE = ObservationSetting("none")
KEY = jax.random.key(0)


def _plain(sdc_xy, sdc_yaw, sdc_speed, objects, sdc_index, roadgraph, config=CFG):
    return _obs(sdc_xy, sdc_yaw, sdc_speed, objects, sdc_index, roadgraph, NONE, KEY, KEY,
                config=config)


def ring(radii, bearings_deg):
    """Points at the given radii / bearings around the origin (ego at origin facing +x)."""
    b = np.deg2rad(np.asarray(bearings_deg, np.float32))
    r = np.asarray(radii, np.float32)
    return np.stack([r * np.cos(b), r * np.sin(b)], -1)


def scene(xy_objects, xy_road, **kw):
    """Ego in slot 0 at the origin facing +x, then the given others."""
    xy = np.concatenate([[[0.0, 0.0]], xy_objects]).astype(np.float32)
    return dict(sdc_xy=np.zeros(2, np.float32), sdc_yaw=np.float32(0.0), sdc_speed=np.float32(0),
                objects=make_objects(xy), sdc_index=np.int32(0),
                roadgraph=make_roadgraph(xy_road), **kw)


def run(setting, sc, ekey=0, skey=1, config=CFG):
    return _obs(sc["sdc_xy"], sc["sdc_yaw"], sc["sdc_speed"], sc["objects"], sc["sdc_index"],
                sc["roadgraph"], get_setting(setting), jax.random.key(ekey), jax.random.key(skey),
                config=config)


def test_sdc_frame_transform_and_features():
    # Ego at (10, 5) heading north (+y) at 5 m/s; it sits in slot 1 and must be excluded.
    objs = make_objects(xy=[[10, 8], [10, 5], [10, 0]], yaw=[math.pi / 2, math.pi / 2, 0.0],
                        vel=[[0, 5], [0, 5], [3, 4]])
    rg = make_roadgraph(xy=[[7, 5]], dirs=[[0, 1]], types=[15])
    obs, sel = _plain(np.array([10, 5], np.float32), np.float32(math.pi / 2), np.float32(5.0),
                      objs, np.int32(1), rg, config=CFG)
    o = np.asarray(obs.objects)
    # 3 m ahead: (3, 0), same heading, 5 m/s.
    np.testing.assert_allclose(o[0], [0.03, 0, 1, 0, 0.1, 1], atol=1e-6)
    # 5 m behind, heading east = -90 deg relative: cos 0, sin -1; speed 5.
    np.testing.assert_allclose(o[1], [-0.05, 0, 0, -1, 0.1, 1], atol=1e-6)
    assert np.asarray(obs.objects_valid).tolist() == [True, True] + [False] * 6
    assert np.asarray(sel.object_index)[:2].tolist() == [0, 2]
    assert not np.any(o[2:])
    r = np.asarray(obs.roadgraph)
    # West of a north-facing ego is its left: (0, +3); direction north -> +x.
    np.testing.assert_allclose(r[0, :4], [0, 0.03, 1, 0], atol=1e-6)
    assert r[0, 4 + 15] == 1 and r[0, 4:24].sum() == 1 and r[0, 24] == 1
    assert r.shape == (8, 25) and not np.any(r[1:])
    np.testing.assert_allclose(np.asarray(obs.sdc_speed), [0.1])


def test_nearest_selection_order_validity_and_padding():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-50, 50, (20, 2)).astype(np.float32)
    valid = np.ones(20, bool)
    valid[np.argmin(np.hypot(*xy.T))] = False  # the nearest object is invalid: never selected
    objs = make_objects(np.concatenate([[[0, 0]], xy]), valid=np.concatenate([[True], valid]))
    rg = make_roadgraph(xy, valid=valid)
    obs, sel = _plain(np.zeros(2, np.float32), np.float32(0), np.float32(0), objs, np.int32(0),
                      rg, config=CFG)
    d = np.where(valid, np.hypot(*xy.T), np.inf)
    want = np.argsort(d)[:8]
    assert np.asarray(sel.roadgraph_index).tolist() == want.tolist()
    assert np.asarray(sel.object_index).tolist() == (want + 1).tolist()
    np.testing.assert_allclose(np.asarray(object_positions(obs)), xy[want], atol=1e-4)
    np.testing.assert_allclose(np.asarray(roadgraph_positions(obs)), xy[want], atol=1e-4)
    # Fewer candidates than slots (3 points for 8 slots, 1 of them invalid): padded, zeroed.
    rg3 = make_roadgraph(xy[:3], valid=[True, False, True])
    obs3, _ = observe_setting_arrays(np.zeros(2), 0.0, 0.0, objs, 0, rg3, NONE, KEY, KEY, CFG)
    assert np.asarray(obs3.roadgraph_valid).tolist() == [True, True] + [False] * 6
    assert obs3.roadgraph.shape == (8, 25) and not np.any(np.asarray(obs3.roadgraph)[2:])


def test_full_is_identity_and_keys_reproduce():
    sc = scene(ring([3, 5, 9], [0, 90, 200]), ring([2, 7], [10, -100]))
    plain, _ = _plain(sc["sdc_xy"], sc["sdc_yaw"], sc["sdc_speed"], sc["objects"],
                      sc["sdc_index"], sc["roadgraph"], config=CFG)
    full, _ = run("full", sc, ekey=3, skey=4)
    jax.tree.map(np.testing.assert_array_equal, full, plain)
    for name in PRESETS:  # same keys -> same observation
        a, _ = run(name, sc, ekey=5, skey=6)
        b, _ = run(name, sc, ekey=5, skey=6)
        jax.tree.map(np.testing.assert_array_equal, a, b)


@pytest.mark.parametrize("name,radius", [("circular_r4", 4.0), ("circular_r6", 6.0)])
def test_circular_fov(name, radius):
    bearings = [0, 90, 180, 270]
    inside = ring([radius - 0.01] * 4, bearings)
    outside = ring([radius + 0.01] * 4, bearings)
    sc = scene(np.concatenate([inside, outside]), np.concatenate([inside, outside]))
    obs, sel = run(name, sc)
    seen = np.asarray(sel.object_index)[np.asarray(obs.objects_valid)]
    assert sorted(seen.tolist()) == [1, 2, 3, 4]
    assert np.asarray(obs.roadgraph_valid).sum() == 4
    assert np.all(np.hypot(*np.asarray(roadgraph_positions(obs)).T) < radius)
    assert not np.any(np.asarray(obs.objects)[~np.asarray(obs.objects_valid)])
    assert not np.any(np.asarray(obs.roadgraph)[~np.asarray(obs.roadgraph_valid)])


def test_conic_fov_edges_and_behind():
    # Half-angle 60 deg: 59 / -59 visible; 61 / -61, 90, 180 (behind) hidden; 0 deg past r hidden.
    pts = np.concatenate([ring([3, 3, 3.9], [59, -59, 0]),
                          ring([3, 3, 3, 1, 4.1], [61, -61, 90, 180, 0])])
    sc = scene(pts, pts)
    obs, sel = run("conic_r4", sc)
    seen = np.asarray(sel.object_index)[np.asarray(obs.objects_valid)]
    assert sorted(seen.tolist()) == [1, 2, 3]
    vis = np.asarray(roadgraph_positions(obs))[np.asarray(obs.roadgraph_valid)]
    np.testing.assert_allclose(sorted(vis[:, 1].tolist()), sorted(pts[:3, 1].tolist()), atol=1e-4)
    # A full-circle cone equals the circular field of view.
    cone = ObservationSetting("c", (ConicFieldOfView(4.0, 2 * math.pi),))
    a, _ = run(cone, sc)
    b, _ = run("circular_r4", sc)
    jax.tree.map(np.testing.assert_array_equal, a, b)


def by_source(obs, sel, what):
    """Positions of the valid slots, ordered by their source index."""
    pos = np.asarray(object_positions(obs) if what == "object" else roadgraph_positions(obs))
    idx = np.asarray(sel.object_index if what == "object" else sel.roadgraph_index)
    valid = np.asarray(obs.objects_valid if what == "object" else obs.roadgraph_valid)
    return pos[valid][np.argsort(idx[valid])]


def test_gaussian_noise_one_offset_per_episode_shifts_everything():
    yaw = np.float32(0.7)
    xy_o = np.random.default_rng(1).uniform(-20, 20, (6, 2))
    xy_r = np.random.default_rng(2).uniform(-20, 20, (6, 2))
    sc = scene(xy_o, xy_r)
    sc["sdc_yaw"] = yaw
    sc["objects"] = sc["objects"].replace(yaw=np.full(7, yaw, np.float32))
    clean, csel = run("full", sc)
    model = GaussianPositionNoise(3.0)
    shifts = []
    for skey in (1, 2, 3):  # same episode, different steps: the same offset
        noisy, nsel = run("gaussian_noise", sc, ekey=7, skey=skey)
        # Slots are ordered by distance to the believed position: match them by source index.
        d_obj = by_source(noisy, nsel, "object") - by_source(clean, csel, "object")
        d_rg = by_source(noisy, nsel, "roadgraph") - by_source(clean, csel, "roadgraph")
        # Every other object and road point moves by the same vector...
        np.testing.assert_allclose(d_obj, np.broadcast_to(d_obj[0], d_obj.shape), atol=1e-3)
        np.testing.assert_allclose(d_rg, np.broadcast_to(d_obj[0], d_rg.shape), atol=1e-3)
        shifts.append(d_obj[0])
        # ... headings, speeds and road directions are untouched.
        np.testing.assert_allclose(noisy.objects[:, 2:6].sum(0), clean.objects[:, 2:6].sum(0),
                                   atol=1e-5)
        np.testing.assert_allclose(noisy.roadgraph[:, 2:].sum(0), clean.roadgraph[:, 2:].sum(0),
                                   atol=1e-5)
    np.testing.assert_array_equal(shifts[0], shifts[1])
    np.testing.assert_array_equal(shifts[0], shifts[2])
    # ... and it is -eps rotated into the ego frame, with eps from the (folded) episode key.
    eps = np.asarray(model.offset(jax.random.fold_in(jax.random.key(7), 0)))
    c, s = np.cos(yaw), np.sin(yaw)
    np.testing.assert_allclose(shifts[0], -np.array([c * eps[0] + s * eps[1],
                                                     -s * eps[0] + c * eps[1]]), atol=1e-3)
    other, _ = run("gaussian_noise", sc, ekey=8, skey=1)
    assert not np.allclose(other.objects, noisy.objects)
    # Offsets over many episodes: zero mean, std sigma, independent x / y.
    offs = np.asarray(jax.vmap(model.offset)(jax.random.split(jax.random.key(0), 4000)))
    assert np.all(np.abs(offs.mean(0)) < 0.2) and np.all(np.abs(offs.std(0) - 3) < 0.15)
    assert abs(np.corrcoef(offs.T)[0, 1]) < 0.05


def test_random_masking_rate_and_independence():
    sc = scene(ring(np.linspace(2, 30, 8), np.linspace(0, 315, 8)), ring([3], [0]))
    keys = jax.random.split(jax.random.key(0), 1000)
    batched = jax.vmap(lambda k: run_masking(sc, k))
    valid = np.asarray(batched(keys))  # [steps, slots]
    hidden = ~valid
    assert abs(hidden.mean() - 0.7) < 0.02
    assert np.all(np.abs(hidden.mean(0) - 0.7) < 0.06)  # every slot ~p
    corr = np.corrcoef(hidden.T)[np.triu_indices(8, 1)]
    assert np.all(np.abs(corr) < 0.12)  # independent across objects
    step_corr = np.corrcoef(hidden[:-1].ravel(), hidden[1:].ravel())[0, 1]
    assert abs(step_corr) < 0.05  # independent across steps
    # Road points are never masked; the episode key plays no part.
    obs, _ = run("random_masking", sc, ekey=1, skey=9)
    assert np.asarray(obs.roadgraph_valid).sum() == 1
    obs2, _ = run("random_masking", sc, ekey=2, skey=9)
    jax.tree.map(np.testing.assert_array_equal, obs, obs2)


def run_masking(sc, step_key):
    obs, _ = observe_setting_arrays(
        sc["sdc_xy"], sc["sdc_yaw"], sc["sdc_speed"], sc["objects"], sc["sdc_index"],
        sc["roadgraph"], PRESETS["random_masking"], jax.random.key(0), step_key, CFG)
    return obs.objects_valid


def test_vmap_matches_per_example():
    scs = [scene(np.random.default_rng(i).uniform(-8, 8, (10, 2)),
                 np.random.default_rng(i + 9).uniform(-8, 8, (12, 2))) for i in range(3)]
    batch = jax.tree.map(lambda *xs: np.stack(xs), *scs)
    ekeys = jax.random.split(jax.random.key(1), 3)
    skeys = jax.random.split(jax.random.key(2), 3)
    setting = get_setting("gaussian_noise+conic_r4+random_masking")
    f = jax.jit(jax.vmap(lambda s, e, k: observe_setting_arrays(
        s["sdc_xy"], s["sdc_yaw"], s["sdc_speed"], s["objects"], s["sdc_index"],
        s["roadgraph"], setting, e, k, CFG)))
    got, _ = f(batch, ekeys, skeys)
    assert got.objects.shape == (3, 8, 6) and got.roadgraph.shape == (3, 8, 25)
    for i, sc in enumerate(scs):
        one, _ = _obs(sc["sdc_xy"], sc["sdc_yaw"], sc["sdc_speed"], sc["objects"],
                      sc["sdc_index"], sc["roadgraph"], setting, ekeys[i], skeys[i], config=CFG)
        jax.tree.map(lambda a, b, i=i: np.testing.assert_allclose(a[i], b, atol=1e-6), got, one)


def _hide_behind(obs, episode_key, step_key):
    return hide_objects(obs, object_positions(obs)[..., 0] >= 0)


def test_settings_compose_and_register():
    assert PAPER_SETTINGS == ("full", "gaussian_noise", "circular_r4", "circular_r6",
                              "conic_r4", "random_masking")
    assert set(PAPER_SETTINGS) < set(PRESETS)  # the registry also holds settings beyond them
    combo = get_setting("gaussian_noise+circular_r4")
    assert [type(m) for m in combo.models] == [GaussianPositionNoise, CircularFieldOfView]
    # The field of view is applied around the believed (noisy) position.
    sc = scene(ring([3.0], [0]), ring([3.0], [0]))
    obs, _ = run(combo, sc, ekey=11)
    noisy, _ = run("gaussian_noise", sc, ekey=11)
    d = float(np.hypot(*np.asarray(object_positions(noisy))[0]))
    assert bool(obs.objects_valid[0]) == (d <= 4.0)
    custom = ObservationSetting("front", (FunctionModel(_hide_behind),))
    obs, sel = run(custom, scene(ring([3, 3], [10, 170]), ring([1], [0])))
    assert np.asarray(sel.object_index)[np.asarray(obs.objects_valid)].tolist() == [1]
    with pytest.raises(ConfigError, match="unknown observation setting 'nope'"):
        get_setting("full+nope")
    with pytest.raises(ConfigError):
        RandomMasking(1.5)
    with pytest.raises(ConfigError):
        ConicFieldOfView(4.0, 0.0)
