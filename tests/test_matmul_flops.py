"""`bench train`'s FLOP count: a scan's body counts once per step, a vmapped batch and the
backward pass are priced, a cond runs one branch (XLA's cost analysis counts a loop once)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

from igdrivsim.core.nn import matmul_flops

PRODUCT = 2 * 8 * 64 * 64  # one [8, 64] @ [64, 64]


def _loss(w, x):
    return (jax.lax.scan(lambda c, _: (jnp.tanh(c @ w), None), x, None, length=90)[0] ** 2).sum()


def test_scan_steps_backward_and_batch_are_counted():
    w, x = jnp.ones((64, 64)), jnp.ones((8, 64))
    # forward, and two products backward (into the carry and into w), at each of 90 steps
    assert matmul_flops(jax.jit(jax.grad(_loss)), w, x) == 3 * PRODUCT * 90
    batched = jax.vmap(jax.grad(_loss), in_axes=(None, 0))
    assert matmul_flops(batched, w, jnp.ones((5, 8, 64))) == 5 * 3 * PRODUCT * 90


def test_cond_counts_the_costlier_branch():
    w, x = jnp.ones((64, 64)), jnp.ones((8, 64))
    assert matmul_flops(lambda w, x: jax.lax.cond(x.sum() > 0, lambda: x @ w, lambda: x),
                        w, x) == PRODUCT


def test_trace_summary_sums_a_kernel_kind_per_timeline_line(tmp_path):
    """`bench train --trace`: a device's kernels are summed per kind (digits folded) and per
    timeline line; host lines are left out when a device is in the trace."""
    import gzip
    import json

    from igdrivsim.bench.train import trace_summary

    meta = [{"ph": "M", "name": "process_name", "pid": 1, "args": {"name": "/device:GPU:0"}},
            {"ph": "M", "name": "process_name", "pid": 2, "args": {"name": "/host:CPU"}},
            {"ph": "M", "name": "thread_name", "pid": 1, "tid": 7, "args": {"name": "Stream #7"}}]
    spans = [{"ph": "X", "pid": 1, "tid": 7, "ts": 0, "dur": 3e6, "name": "gemm_fusion_dot_12"},
             {"ph": "X", "pid": 1, "tid": 7, "ts": 3e6, "dur": 1e6, "name": "gemm_fusion_dot_3"},
             {"ph": "X", "pid": 1, "tid": 7, "ts": 4e6, "dur": 1e6, "name": "loop_add_fusion"},
             {"ph": "X", "pid": 2, "tid": 1, "ts": 0, "dur": 9e6, "name": "python"}]
    path = tmp_path / "plugins" / "profile" / "run"
    path.mkdir(parents=True)
    with gzip.open(path / "perfetto_trace.json.gz", "wt") as f:
        json.dump({"traceEvents": meta + spans}, f)
    out = trace_summary(str(tmp_path))
    assert out["trace_span_s"] == 5.0 and out["trace_busy_s"] == 5.0
    assert out["trace_top"][0] == {"name": "Stream #N: gemm_fusion_dot_N", "seconds": 4.0,
                                   "share": 0.8, "count": 2}
    assert [r["name"] for r in out["trace_top"]] == ["Stream #N: gemm_fusion_dot_N",
                                                      "Stream #N: loop_add_fusion"]


def test_bench_train_times_the_update_and_its_parts():
    """`bench train --parts`: the record counts one update's work from the method's passes and
    times the update's parts alone."""
    from igdrivsim.bench.train import bench_profile

    r = bench_profile("smoke", "bc", updates=1, obs="full", parts=True)
    assert r["params_per_seed"] > 0 and r["seconds_per_update"] > 0
    assert r["forward_matmul_flops_per_step"] > 0
    # smoke: 2 seeds x 4 scenarios x 80 steps x 2 passes, 2 minibatches each
    assert r["scenario_steps_per_s"] * r["seconds_per_update"] == pytest.approx(2 * 4 * 80 * 2,
                                                                               rel=1e-2)
    assert r["grad_steps_per_s"] * r["seconds_per_update"] == pytest.approx(2 * 2 * 2, rel=1e-2)
    assert set(r["parts_s"]) == {"record", "observe", "collect", "forward_backward"}
    assert all(v > 0 for v in r["parts_s"].values())


def test_bench_train_times_a_method_without_an_expert_loss():
    """ADVISOR reports no ``bc_loss``: its record carries the loss it trains, ``teacher_ce``."""
    from igdrivsim.bench.train import bench_profile

    r = bench_profile("smoke", "advisor", updates=1, obs="circular_r4")
    assert r["seconds_per_update"] > 0 and r["teacher_ce"] > 0 and "bc_loss" not in r
