"""Line-of-sight occlusion on constructed geometry, stacked with other settings, and its
registry entry."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.errors import ConfigError
from igdrivsim.observation import (
    PRESET_TITLES,
    PRESETS,
    LineOfSightOcclusion,
    Observation,
    apply_setting,
    get_setting,
    line_of_sight,
    stack_settings,
)

KEYS = (jax.random.key(0), jax.random.key(1))


def same(a: Observation, b: Observation) -> bool:
    return all(jax.tree.leaves(jax.tree.map(lambda x, y: bool(jnp.array_equal(x, y)), a, b)))


def observation(objects, road, valid=None) -> Observation:
    """Objects ``(x, y, yaw)`` and road points ``(x, y)`` in metres, in the ego frame."""
    objects = np.asarray(objects, np.float32)
    n = len(objects)
    valid = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    feats = np.stack([objects[:, 0] / 100, objects[:, 1] / 100, np.cos(objects[:, 2]),
                      np.sin(objects[:, 2]), np.full(n, 0.2), valid], 1).astype(np.float32)
    road = np.asarray(road, np.float32)
    rg = np.zeros((len(road), 25), np.float32)
    rg[:, :2], rg[:, 2], rg[:, 24] = road / 100, 1.0, 1.0
    return Observation(jnp.asarray(feats * valid[:, None]), jnp.asarray(valid), jnp.asarray(rg),
                       jnp.ones(len(road), bool), jnp.full((1,), 0.2, jnp.float32),
                       jnp.zeros((1,), jnp.float32))


def test_what_a_car_ahead_hides():
    obs = observation(
        objects=[(10, 0, 0), (20, 0, 0), (20, 10, 0), (5, -5, 0), (20, 3, 0)],
        road=[(15, 0.5), (5, 0), (10, 0), (-10, 0), (30, 20)])
    keep_objects, keep_road = line_of_sight(obs, 4.5, 2.0)
    # the occluder itself, and what is beside or in front of it, stay; (20, 3): the sight line
    # passes 1.35-1.65 m beside the 1 m half-width box
    assert keep_objects.tolist() == [True, False, True, True, True]
    # behind the box, under it; in front of it, behind the ego, far to the side
    assert keep_road.tolist() == [False, True, False, True, True]


def test_heading_turns_the_box():
    along = observation([(10, 0, 0), (20, 3, 0)], [(0, 1)])
    across = observation([(10, 0, math.pi / 2), (20, 3, 0)], [(0, 1)])
    assert bool(line_of_sight(along, 4.5, 2.0)[0][1])  # passes beside a car seen end-on
    assert not bool(line_of_sight(across, 4.5, 2.0)[0][1])  # blocked by a car seen side-on


def test_invalid_objects_and_a_box_around_the_ego_occlude_nothing():
    hidden_occluder = observation([(10, 0, 0), (20, 0, 0)], [(15, 0)], valid=[False, True])
    assert line_of_sight(hidden_occluder, 4.5, 2.0)[0][1]
    assert line_of_sight(hidden_occluder, 4.5, 2.0)[1][0]
    overlapping = observation([(0.5, 0, 0), (20, 0, 0)], [(15, 0)])
    assert line_of_sight(overlapping, 4.5, 2.0)[0].all()
    assert line_of_sight(overlapping, 4.5, 2.0)[1].all()


def _first(stacked):
    return jax.tree.map(lambda x: x[0], stacked)


def test_a_stack_of_one_equals_the_setting_and_composes():
    obs = observation([(10, 0, 0), (20, 0, 0), (3, 2, 0), (7, -3, 0.3)],
                      [(15, 0.5), (5, 0), (2, 1), (-10, 0), (8, 8)])
    for name in ("occlusion", "occlusion+circular_r6", "gaussian_noise+occlusion",
                 "circular_r6+occlusion"):
        static = apply_setting(get_setting(name), obs, *KEYS)
        data = apply_setting(_first(stack_settings([name])), obs, *KEYS)
        assert same(static, data), name
    assert not same(apply_setting(get_setting("occlusion"), obs, *KEYS), obs)
    # hiding first and occluding after differ from the other order: no shared program
    assert stack_settings(["circular_r6+occlusion", "occlusion+circular_r6"]) is None
    assert stack_settings(["occlusion+occlusion", "full"]) is not None  # two slots, both off


def test_a_stack_with_and_without_occlusion_matches_each_alone():
    obs = observation([(10, 0, 0), (20, 0, 0), (3, 2, 0)], [(15, 0.5), (5, 0), (2, 1)])
    names = ["full", "occlusion", "circular_r4", "circular_r6+occlusion"]
    stacked = stack_settings(names)
    together = jax.vmap(lambda p: apply_setting(p, obs, *KEYS))(stacked)
    for g, name in enumerate(names):
        alone = apply_setting(get_setting(name), obs, *KEYS)
        got = jax.tree.map(lambda x, g=g: x[g], together)
        assert same(alone, got), name
    # the paper's settings alone carry no occluder, so they never trace the geometry
    assert not any(isinstance(m, LineOfSightOcclusion)
                   for m in stack_settings(["full", "circular_r4"]).models)


def test_registry_entry_and_bad_sizes():
    assert PRESETS["occlusion"].models == (LineOfSightOcclusion(),)
    assert PRESET_TITLES["occlusion"] == "Line-of-sight occlusion"
    with pytest.raises(ConfigError, match="length and width"):
        LineOfSightOcclusion(length=-1.0)
    assert LineOfSightOcclusion(0.0, 0.0) == LineOfSightOcclusion().neutral()
