"""The fast simulator path (crop + candidates + unsorted selection) equals the naive one."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from igdrivsim.errors import ConfigError
from igdrivsim.observation import PRESETS, ObservationConfig
from igdrivsim.observation.candidates import CandidateConfig, observe_batch_with_candidates

WOMD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "womd"
EXAMPLE = WOMD / "motion_data_one_example.tfrecord"
needs_womd = pytest.mark.skipif(not EXAMPLE.exists(), reason=f"real WOMD sample absent: {EXAMPLE}")


@needs_womd
def test_fast_equals_naive_on_a_real_scenario():
    """Same metrics and the same observation at every step (objects slot for slot, roadgraph
    points as a set); small capacities so that the candidates are re-selected several times."""
    from igdrivsim.data import load_scenario
    from igdrivsim.observation.bench import _batch, episode

    sc = _batch([load_scenario(EXAMPLE)], 2)  # different noise: repairs for one or both examples
    cfg = ObservationConfig(num_objects=8, num_roadgraph_points=128)
    cands = CandidateConfig(num_candidates=256, band=16)
    common = dict(setting_name="gaussian_noise", cand_config=cands, collect=True)
    key = jax.random.PRNGKey(3)
    naive = jax.jit(lambda s, k: episode(s, k, impl="naive", obs_config=cfg, **common))(sc, key)
    fast = jax.jit(lambda s, k: episode(s, k, impl="fast", obs_config=cfg, **common))(sc, key)
    (m_n, _, _, _, o_n), (m_f, _, sel_f, sorts_f, o_f) = naive, fast
    assert int(sel_f.min()) >= 3  # the exactness checks did trigger re-selections and re-sorts
    assert int(sorts_f.min()) >= 3 and sorts_f[0] != sorts_f[1]
    np.testing.assert_array_equal(m_n.overlap, m_f.overlap)
    np.testing.assert_array_equal(m_n.offroad, m_f.offroad)
    np.testing.assert_allclose(m_n.log_divergence, m_f.log_divergence, atol=1e-6)
    np.testing.assert_allclose(o_n.objects, o_f.objects, atol=1e-6)
    np.testing.assert_allclose(o_n.sdc_speed, o_f.sdc_speed, atol=1e-6)
    np.testing.assert_allclose(o_n.sdc_yaw_rate, o_f.sdc_yaw_rate, atol=1e-6)
    assert np.abs(np.asarray(o_n.sdc_yaw_rate)).max() > 0  # the policy turns: rates are seen
    assert np.asarray(o_n.roadgraph_valid).sum(-1).min() == 128
    np.testing.assert_array_equal(o_n.roadgraph_valid, o_f.roadgraph_valid)
    # The same points (as a set: the fast path keeps them in its stored, roughly nearest-first,
    # order).
    assert_same_points(o_n.roadgraph, o_f.roadgraph)


@needs_womd
def test_fast_falls_back_to_the_exact_top_k_on_duplicate_points():
    """Every road point repeated 40 times: piles of equal distances at the boundary defeat the
    integer sort, so every repair runs down to the exact top-k; the points seen still match."""
    from igdrivsim.data import load_scenario
    from igdrivsim.observation.bench import _batch, episode

    sc = load_scenario(EXAMPLE)
    rg = sc.roadgraph
    keep = np.flatnonzero(rg.valid)[: rg.valid.shape[0] // 40]
    rep = lambda a: np.repeat(a[keep], 40, axis=0)  # noqa: E731
    piles = rg.replace(xyz=rep(rg.xyz), dir=rep(rg.dir), type=rep(rg.type), id=rep(rg.id),
                       valid=rep(rg.valid))
    sc = _batch([sc.replace(roadgraph=piles)], 1)
    cfg = ObservationConfig(num_objects=8, num_roadgraph_points=100)  # boundary in a pile
    common = dict(setting_name="full", obs_config=cfg, collect=True,
                  cand_config=CandidateConfig(num_candidates=240, band=16))
    key = jax.random.PRNGKey(0)
    naive = jax.jit(lambda s, k: episode(s, k, impl="naive", **common))(sc, key)
    fast = jax.jit(lambda s, k: episode(s, k, impl="fast", **common))(sc, key)
    assert int(fast[2][0]) > 40  # re-selected at most steps
    np.testing.assert_array_equal(naive[-1].roadgraph_valid, fast[-1].roadgraph_valid)
    assert_same_points(naive[-1].roadgraph, fast[-1].roadgraph)


def assert_same_points(a, b, atol: float = 1e-5) -> None:
    """Every step's valid roadgraph rows of ``a`` and ``b`` match as sets (each row of one has a
    row of the other within ``atol`` in every feature), whatever their slot order."""
    a, b = (np.asarray(x).reshape(-1, *np.shape(x)[-2:]) for x in (a, b))
    for x, y in zip(a, b, strict=True):
        far = np.abs(x[:, None, :] - y[None, :, :]).max(-1) > atol
        assert far.all(1).sum() == 0 and far.all(0).sum() == 0


def test_candidates_must_cover_the_capacity():
    with pytest.raises(ConfigError, match="num_candidates"):
        observe_batch_with_candidates(None, PRESETS["full"], None, None, None,
                                      ObservationConfig(num_roadgraph_points=100),
                                      CandidateConfig(num_candidates=50))


def test_bench_cli_rejects_bad_options(capsys):
    from igdrivsim.cli import main

    assert main(["bench", "sim", "--batches", "1,x"]) == 2
    assert main(["bench", "sim", "--impls", "naive,bogus"]) == 2
    assert main(["bench", "sim", "--candidates", "10"]) == 2
    assert main(["bench", "sim", "--band", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(e.startswith("igdrivsim bench sim: error:") for e in err)


@needs_womd
@pytest.mark.parametrize("distinct", [False, True])
def test_bench_cli_writes_rows(tmp_path, capsys, distinct):
    import json

    from igdrivsim.cli import main

    out = tmp_path / "bench.json"
    assert main(["bench", "sim", "--batches", "2", "--impls", "fast", "--repeats", "1",
                 "--out", str(out)] + (["--distinct", "--data", str(WOMD)] if distinct else [])
                ) == 0
    result = json.loads(out.read_text())
    assert result["distinct"] is distinct
    rows = result["rows"]
    assert [(r["batch"], r["impl"]) for r in rows] == [(2, "fast")]
    assert rows[0]["scenario_steps_per_s"] > 0 and rows[0]["offroad_steps"] == 0
    assert "fast" in capsys.readouterr().out


def test_packed_nearest_is_the_top_k_set_or_says_so():
    """The int-sort selection equals the top-k set whenever it reports ok, on inputs built to
    defeat it: exact duplicates, distances within one quantum, fewer valid points than slots."""
    from igdrivsim.observation.candidates import _packed_nearest
    from igdrivsim.observation.features import nearest

    k, n = 300, 100
    rng = np.random.default_rng(0)
    d = rng.uniform(0.0, 60.0, size=(64, k)).astype(np.float32)
    d[8:16, 90:110] = 20.0  # 20 exact duplicates across the boundary
    d[16:32, 80:120] = 20.0 + rng.integers(0, 3, size=(16, 40)) * 1e-5  # within one quantum
    d[32:40, 95:105] = 20.0 + np.arange(10) * 1e-5
    valid = np.ones((64, k), bool)
    valid[40:48] = rng.uniform(size=(8, k)) < 0.3  # fewer valid than slots
    d2 = jnp.asarray(d) ** 2
    tie = jnp.broadcast_to(jnp.arange(k, dtype=jnp.int32), (64, k))
    pos, ok = jax.jit(jax.vmap(lambda a, v, t: _packed_nearest(a, v, t, n, 400.0)))(
        d2, jnp.asarray(valid), tie)
    want, want_valid = jax.vmap(lambda a, v: nearest(a, v, n))(d2, jnp.asarray(valid))
    pos, ok, want, want_valid = map(np.asarray, (pos, ok, want, want_valid))
    assert ok[:8].all() and ok[40:].all() and not ok.all()  # clusters of > 8 fall back
    for i in np.flatnonzero(ok):
        got = set(pos[i][valid[i][pos[i]]].tolist())
        assert got == set(want[i][want_valid[i]].tolist()), i


@pytest.mark.parametrize("band", [0, 16])
def test_band_select_is_the_top_k_set_or_says_so(band):
    """The stored-order selection equals the top-k set whenever it reports exact: on nearly
    sorted orders (the normal case, where it must succeed), shuffled orders, duplicates at the
    boundary, and fewer valid points than slots (valid first, or not)."""
    from igdrivsim.observation.candidates import _band_select
    from igdrivsim.observation.features import nearest

    k, n, rows = 300, 100, 80
    rng = np.random.default_rng(1)
    xy = rng.uniform(-50.0, 50.0, size=(rows, k, 2)).astype(np.float32)
    ego = rng.normal(size=(rows, 2)).astype(np.float32)  # the stored order is around 0
    order = np.argsort(np.hypot(xy[..., 0], xy[..., 1]), axis=-1)
    xy = np.take_along_axis(xy, order[..., None], axis=1)
    valid = np.ones((rows, k), bool)
    xy[20:30] = xy[20:30, rng.permutation(k)]  # shuffled: must not pass as exact
    xy[30:40, n - 5:n + 5] = xy[30:40, n:n + 1]  # duplicates across the boundary
    valid[40:50, 90:] = False  # few valid, first
    valid[50:60] = rng.uniform(size=(10, k)) < 0.3  # few valid, scattered
    d2 = jnp.asarray(np.sum((xy - ego[:, None]) ** 2, axis=-1))
    tie = jnp.broadcast_to(jnp.arange(k, dtype=jnp.int32), (rows, k))
    pos, exact, _ = jax.jit(jax.vmap(lambda a, v, t: _band_select(a, v, t, n, band, 400.0)))(
        d2, jnp.asarray(valid), tie)
    want, want_valid = jax.vmap(lambda a, v: nearest(a, v, n))(d2, jnp.asarray(valid))
    pos, exact, want, want_valid = map(np.asarray, (pos, exact, want, want_valid))
    pos = np.concatenate([np.broadcast_to(np.arange(n - band), (rows, n - band)),
                          n - band + pos], axis=1)
    assert exact[40:50].all() and (exact[:20].all() or band == 0)
    assert not exact[20:30].any() and not exact[50:60].any()
    for i in np.flatnonzero(exact):
        got = set(pos[i][valid[i][pos[i]]].tolist())
        assert got == set(want[i][want_valid[i]].tolist()), i


@pytest.mark.parametrize("k", [5, 32, 3000])
def test_packed_order_sorts_and_puts_invalid_last(k):
    """At every size, including those whose invalid code is not a float32 (it once sorted first)."""
    from igdrivsim.observation.candidates import _packed_order

    rng = np.random.default_rng(k)
    e = rng.uniform(0.0, 100.0, size=k).astype(np.float32)
    valid = rng.uniform(size=k) < 0.7
    order = np.asarray(_packed_order(jnp.asarray(e), jnp.asarray(valid), 400.0)[0])
    nv = int(valid.sum())
    assert valid[order[:nv]].all() and not valid[order[nv:]].any()
    quantum = 400.0 / 2 ** (31 - (k - 1).bit_length())
    assert np.all(np.diff(e[order[:nv]]) >= -1.01 * quantum)
