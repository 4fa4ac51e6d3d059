"""The driving network's fast forms compute what their plain forms compute."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from igdrivsim.policy.network import MLP, PooledMLP, dense_2d


def test_pooled_mlp_is_the_mlp_of_the_concatenation():
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    h = jax.random.normal(keys[0], (2, 3, 9, 6))  # [..., N points, D]
    pooled = jax.random.normal(keys[1], (2, 3, 6))
    fast = PooledMLP((8, 5))
    params = fast.init(keys[2], h, pooled)
    # the same parameter tree as an MLP on [h, pooled] (checkpoints carry over)
    concat = jnp.concatenate([h, jnp.broadcast_to(pooled[..., None, :], h.shape)], -1)
    plain = MLP((8, 5))
    assert (jax.tree.map(jnp.shape, params)
            == jax.tree.map(jnp.shape, plain.init(keys[2], concat)))
    np.testing.assert_allclose(fast.apply(params, h, pooled), plain.apply(params, concat),
                               rtol=1e-5, atol=1e-5)


def test_dense_2d_keeps_leading_axes():
    import flax.linen as nn

    x = jax.random.normal(jax.random.PRNGKey(1), (4, 3, 2, 7))
    layer = nn.Dense(5)
    params = layer.init(jax.random.PRNGKey(2), x)
    np.testing.assert_allclose(layer.apply(params, x),
                               jax.jit(lambda p, x: dense_2d(layer.bind(p), x))(params, x),
                               rtol=1e-5, atol=1e-6)


def test_max_per_type_pools_each_road_type_separately():
    from igdrivsim.data.scenario import RG_NUM_TYPES
    from igdrivsim.policy.network import max_per_type

    x = jnp.array([[1.0, -5.0], [3.0, 2.0], [-2.0, 7.0], [9.0, 9.0]])  # [N=4, D=2]
    types = jnp.array([0, 0, 1, RG_NUM_TYPES])  # the last point: invalid
    pooled = max_per_type(jnp.stack([x, -x]), jnp.stack([types, types]))  # two sets
    assert pooled.shape == (2, RG_NUM_TYPES, 2)
    np.testing.assert_array_equal(pooled[0, :3], [[3.0, 2.0], [-2.0, 7.0], [0.0, 0.0]])
    np.testing.assert_array_equal(pooled[1, :2], [[-1.0, 5.0], [2.0, -7.0]])
    assert not pooled[:, 2:].any()  # types with no point: zeros


def test_type_pooled_mlp_is_the_mlp_of_each_point_next_to_its_types_pool():
    from igdrivsim.policy.network import max_per_type

    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    h = jax.random.normal(keys[0], (2, 9, 6))  # [B, N points, D]
    types = jax.random.randint(keys[1], (2, 9), 0, 4)
    pooled = max_per_type(h, types)  # [B, T, D]
    fast = PooledMLP((8, 5))
    params = fast.init(keys[2], h, pooled, types)
    # each point next to the max over the points of its own type, by a plain loop
    own = np.zeros_like(h)
    for b in range(2):
        for i in range(9):
            own[b, i] = np.asarray(h)[b][np.asarray(types[b]) == int(types[b, i])].max(0)
    plain = MLP((8, 5)).apply(params, jnp.concatenate([h, own], -1))
    np.testing.assert_allclose(fast.apply(params, h, pooled, types), plain, rtol=1e-5,
                               atol=1e-5)


def _paper_network(method: str):
    import dataclasses

    from igdrivsim.core.nn import matmul_flops
    from igdrivsim.policy.act import example_observation
    from igdrivsim.policy.network import apply_step, count_params, init_params, initial_carry
    from igdrivsim.training.config import get_profile

    base = get_profile("paper")
    config = dataclasses.replace(base, training=dataclasses.replace(
        base.training, method=method)).validate()
    obs = example_observation(config.obs_config)
    params = init_params(config.policy, jax.random.PRNGKey(0), obs)
    flops = matmul_flops(lambda p, o: apply_step(config.policy, p, initial_carry(
        config.policy), o, jnp.zeros((), bool)), params, obs)
    return config, count_params(params), flops


def test_paper_profile_is_the_original_network_and_budget():
    """The original code: 4,255,099 parameters (BC), 4,583,548 (BC-RL), about 10.2 MFLOP of
    matrix products forward per step at 32 objects and 1,500 road points; BC one Adam step per
    batch of 256, BC-RL 4 PPO epochs of 4 minibatches."""
    bc, bc_params, bc_flops = _paper_network("bc")
    rl, rl_params, _ = _paper_network("bc_rl")
    assert abs(bc_params / 4_255_099 - 1) < 0.02
    assert abs(rl_params / 4_583_548 - 1) < 0.02
    assert abs(bc_flops / 10.2e6 - 1) < 0.2
    assert not bc.policy.value_head and rl.policy.value_head
    assert (bc.observation.num_objects, bc.observation.num_roadgraph_points) == (32, 1500)
    assert bc.data.batch_size == 256 and bc.training.grad_clip == 0.5
    assert bc.sgd_passes == (1, 1) and rl.sgd_passes == (4, 4)


def test_laptop_profile_passes_are_the_same_for_every_method():
    import dataclasses

    from igdrivsim.training.config import get_profile

    base = get_profile("laptop")
    for method in ("bc", "bc_rl"):
        config = dataclasses.replace(base, training=dataclasses.replace(base.training,
                                                                        method=method))
        assert config.sgd_passes == (2, 4)


def test_dropping_the_value_head_leaves_the_other_parameters_as_they_were():
    """A BC network has no value head (nothing trains it); the other parameters initialise
    exactly as with one, so BC learns the same policy either way."""
    import dataclasses

    from igdrivsim.observation import ObservationConfig
    from igdrivsim.policy.act import example_observation
    from igdrivsim.policy.network import apply_step, init_params, initial_carry
    from igdrivsim.training.config import get_profile

    config = get_profile("smoke").policy
    obs = example_observation(ObservationConfig(4, 32))
    with_value = init_params(config, jax.random.PRNGKey(5), obs)
    without = init_params(dataclasses.replace(config, value_head=False), jax.random.PRNGKey(5),
                          obs)
    inner = dict(with_value["params"])
    assert set(inner) - set(without["params"]) == {"value_mlp", "value_out"}
    kept = {"params": {k: v for k, v in inner.items() if k in without["params"]}}
    jax.tree.map(np.testing.assert_array_equal, kept, without)
    carry = initial_carry(config)
    _, logits, _ = apply_step(config, with_value, carry, obs, jnp.ones((), bool))
    _, logits_no, value = apply_step(dataclasses.replace(config, value_head=False), without,
                                     carry, obs, jnp.ones((), bool))
    np.testing.assert_array_equal(logits, logits_no)
    assert float(value) == 0.0


def test_a_run_config_written_before_the_two_shapes_reads_as_the_pooled_network():
    import dataclasses

    import pytest

    from igdrivsim.errors import ConfigError
    from igdrivsim.policy.network import POOLED_NETWORK
    from igdrivsim.training.config import from_dict, get_profile, to_dict, with_overrides

    laptop = get_profile("laptop")
    old = to_dict(laptop)
    for name in (*POOLED_NETWORK, "value_head"):
        del old["policy"][name]
    # its network as it was trained, a value head included (a BC run's checkpoint holds one)
    assert from_dict(old) == dataclasses.replace(laptop, policy=dataclasses.replace(
        laptop.policy, value_head=True))
    # resuming it: the method would drop the head, unless the command keeps it
    bc = with_overrides(laptop, ["training.method=bc"])
    assert not bc.validate().policy.value_head
    kept = with_overrides(bc, ["policy.value_head=true"]).validate()
    assert kept.policy.value_head and to_dict(kept)["policy"] == to_dict(from_dict(
        to_dict(kept)))["policy"]
    with pytest.raises(ConfigError, match="learns values"):
        with_overrides(laptop, ["training.method=bc_rl", "policy.value_head=false"]).validate()
    paper = get_profile("paper")
    assert from_dict(to_dict(paper)) == paper
    assert dataclasses.replace(paper.policy, remat=False) == type(paper.policy)()
