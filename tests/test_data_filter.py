"""The paper's filter (hand-computed cases), the manifest, parts/merge/resume and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from igdrivsim.cli import main
from igdrivsim.data import Capacities, decode_scenario_id, write_tfexample
from igdrivsim.data import filter as filt
from igdrivsim.data.filter import (
    FilterConfig,
    intersecting_objects,
    keep,
    merge,
    run_filter,
    scenario_stats,
    sdc_mean_speed,
    segments_intersect,
)
from igdrivsim.data.manifest import iter_manifest_scenarios, read_manifest
from igdrivsim.data.scenario import NUM_STEPS, empty_scenario, encode_scenario_id
from igdrivsim.data.tfrecord import write_records
from igdrivsim.errors import ConfigError, DataError

WOMD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "womd"
needs_womd = pytest.mark.skipif(not (WOMD / "motion_data_one_example.tfrecord").exists(),
                                reason=f"real WOMD samples not found in {WOMD}")
T = np.arange(NUM_STEPS) * 0.1


def scene(sdc_speed=1.0, others=(), sid="c", ooi=()):
    """SDC (slot 0) drives east along y=0 from x=0 at ``sdc_speed`` m/s; ``others`` are
    ``(x[T], y[T], valid[T])`` paths for slots 1.. ."""
    s = empty_scenario(Capacities(1 + len(others), 4, 1))
    tr, md = s.trajectory, s.metadata
    tr.x[0], tr.y[0], tr.vel_x[0], tr.valid[0] = sdc_speed * T, 0.0, sdc_speed, True
    md.is_sdc[0] = True
    for i, (x, y, valid) in enumerate(others, 1):
        tr.x[i], tr.y[i], tr.valid[i] = x, y, valid
    md.valid[:] = tr.valid.any(1)
    md.id[:] = np.arange(len(md.id))
    md.object_type[:] = 1
    for i in ooi:
        md.objects_of_interest[i] = True
    return s.replace(scenario_id=encode_scenario_id(sid))


ALL = np.ones(NUM_STEPS, bool)


def crossing(x0=4.0, valid=ALL):
    """Walks north along x=x0 from y=-5 to y=+4.1 (crosses y=0 at t=5 s)."""
    return np.full(NUM_STEPS, x0), -5 + T, valid


def test_segments_intersect_hand_cases():
    p = lambda *v: np.array(v, float)
    cases = [  # (p0, p1, q0, q1, expected)
        (p(0, 0), p(2, 2), p(0, 2), p(2, 0), True),  # X
        (p(0, 0), p(2, 0), p(0, 1), p(2, 1), False),  # parallel
        (p(0, 0), p(2, 0), p(1, 0), p(3, 0), True),  # collinear overlap
        (p(0, 0), p(1, 0), p(2, 0), p(3, 0), False),  # collinear, disjoint
        (p(0, 0), p(1, 0), p(1, 0), p(1, 5), True),  # touching end points
        (p(0, 0), p(2, 0), p(1, 0), p(1, 3), True),  # T junction
        (p(0, 0), p(2, 0), p(1, 0.1), p(1, 3), False),  # T just short
        (p(0, 0), p(2, 0), p(1, 0), p(1, 0), True),  # zero-length segment on the path
        (p(0, 0), p(2, 0), p(3, 0), p(3, 0), False),  # zero-length segment beyond it
        (p(0, 0), p(2, 2), p(3, 3), p(4, 0), False),  # would cross the extension only
    ]
    got = [bool(segments_intersect(*c[:4])) for c in cases]
    assert got == [c[4] for c in cases]
    # Broadcasting: one segment against a batch.
    q0 = np.array([[0, 2], [0, 1]], float)
    q1 = np.array([[2, 0], [2, 1]], float)
    assert segments_intersect(p(0, 0), p(2, 2), q0, q1).tolist() == [True, True]


def test_interactive_hand_cases():
    # SDC covers x in [0, 9] at 1 m/s.
    assert intersecting_objects(scene(others=[crossing()])).tolist() == [False, True]
    parallel = (T * 1.0, np.full(NUM_STEPS, 3.0), ALL)
    assert not intersecting_objects(scene(others=[parallel])).any()
    beyond = crossing(x0=12.0)  # crosses the SDC's line beyond where the SDC ever drives
    assert not intersecting_objects(scene(others=[beyond])).any()
    # The crossing segment (t=4.9 s .. 5.1 s) is invalid: the gap breaks the path.
    gap = ALL.copy()
    gap[49:52] = False
    assert not intersecting_objects(scene(others=[crossing(valid=gap)])).any()
    # ... but it is the other's path, not timing, that matters: valid only before and after.
    late = ALL.copy()
    late[:60] = False
    assert not intersecting_objects(scene(others=[crossing(valid=late)])).any()
    # SDC validity matters too: the SDC path ends at x=3.9 if invalid after t=3.9 s.
    s = scene(others=[crossing()])
    s.trajectory.valid[0, 40:] = False
    assert not intersecting_objects(s).any()
    # A stopped object sitting on the SDC's path is crossed (its path is a point).
    parked = (np.full(NUM_STEPS, 2.0), np.zeros(NUM_STEPS), ALL)
    assert intersecting_objects(scene(others=[parked, crossing(x0=20)])).tolist() == [
        False, True, False]


def test_mean_speed_over_valid_steps_only():
    s = scene(sdc_speed=0.8)
    s.trajectory.valid[0, 50:] = False
    s.trajectory.vel_x[0, 50:] = 100.0  # garbage at invalid steps must not count
    s.trajectory.vel_y[0, :10] = 0.6  # speed = hypot(0.8, 0.6) = 1.0 on 10 of 50 valid steps
    assert sdc_mean_speed(s) == pytest.approx((10 * 1.0 + 40 * 0.8) / 50)
    never = scene()
    never.trajectory.valid[0] = False
    assert sdc_mean_speed(never) == 0.0


def test_keep_decisions_and_thresholds():
    paper, ooi = FilterConfig(), FilterConfig(criterion="objects_of_interest")
    fast_cross = scenario_stats(scene(1.0, [crossing()]))
    slow_cross = scenario_stats(scene(0.6, [crossing(x0=2.0)]))
    fast_flag = scenario_stats(scene(1.0, [crossing(x0=50.0)], ooi=[1]))
    assert fast_cross["interactive"] and slow_cross["interactive"]
    assert fast_cross["objects_of_interest"] == 0 and fast_flag["objects_of_interest"] == 1
    assert [keep(st, paper) for st in (fast_cross, slow_cross, fast_flag)] == [True, False, False]
    assert [keep(st, ooi) for st in (fast_cross, slow_cross, fast_flag)] == [False, False, True]
    assert keep(slow_cross, FilterConfig(min_speed=0.5))
    assert keep(scenario_stats(scene(0.7, [crossing(x0=2.0)])), paper)  # >= is inclusive
    with pytest.raises(ConfigError):
        FilterConfig(criterion="nope")
    with pytest.raises(ConfigError):
        FilterConfig(min_speed=-1)


@needs_womd
def test_real_samples_decisions():
    from igdrivsim.data import load_scenario

    ex = scenario_stats(load_scenario(WOMD / "motion_data_one_example.tfrecord", caps=None))
    sc = scenario_stats(load_scenario(WOMD / "motion_data_one_scenario.tfrecord", caps=None))
    assert ex["interactive"] and ex["sdc_mean_speed"] > 5 and keep(ex)
    assert sc["sdc_mean_speed"] < 0.01 and not keep(sc)  # the SDC stands still


def _shards(tmp_path) -> list[str]:
    """Two shards: kept, slow, unflagged-interactive / no interaction, kept, bad record."""
    a = tmp_path / "data" / "a.tfrecord"
    b = tmp_path / "data" / "b.tfrecord"
    write_tfexample(a, [scene(1.0, [crossing()], sid="a0", ooi=[1]),
                        scene(0.3, [crossing(x0=2.0)], sid="a1")])
    from igdrivsim.data.tfexample import encode_tfexample

    write_records(b, [encode_tfexample(scene(2.0, [crossing(x0=50)], sid="b0", ooi=[1])),
                      encode_tfexample(scene(2.0, [crossing()], sid="b1")), b"\x1a\x02no"])
    return [str(a), str(b)]


def test_run_filter_manifest_counts_resume_parts(tmp_path, monkeypatch):
    files = _shards(tmp_path)
    out = tmp_path / "out"
    with pytest.raises(DataError, match=r"b.tfrecord, record 2: unknown record format"):
        run_filter(files, str(out), progress=False)
    counts = run_filter(files, str(out), skip_bad=True, progress=False)
    assert counts["scenarios"] == 4 and counts["bad_records"] == 1 and counts["kept"] == 2
    assert counts["interactive"] == 3 and counts["fast_enough"] == 3
    assert counts["objects_of_interest_and_fast"] == 2
    rows = read_manifest(out, kept_only=False)
    assert [(Path(r["file"]).name, r["record"], r["scenario_id"], r["kept"]) for r in rows] == [
        ("a.tfrecord", 0, "a0", True), ("a.tfrecord", 1, "a1", False),
        ("b.tfrecord", 0, "b0", False), ("b.tfrecord", 1, "b1", True)]
    assert set(rows[0]) >= {"file", "record", "scenario_id", "sdc_mean_speed", "interactive",
                            "objects_of_interest", "kept"}
    assert json.loads((out / "counts.json").read_text()) == counts
    assert json.loads((out / "filter_config.json").read_text())["criterion"] == "paper"
    kept = read_manifest(out / "manifest.jsonl")
    scenarios = [s for _, s in iter_manifest_scenarios(kept, Capacities(4, 8, 2))]
    assert [decode_scenario_id(s.scenario_id) for s in scenarios] == ["a0", "b1"]
    assert scenarios[0].num_objects == 4

    # Re-running skips finished shards (computing one would fail now).
    def boom(*args, **kwargs):
        raise AssertionError("finished shard recomputed")

    monkeypatch.setattr(filt, "filter_shard", boom)
    again = run_filter(files, str(out), FilterConfig("objects_of_interest"), progress=False)
    assert again["kept"] == 2 and again["criterion"] == "objects_of_interest"
    assert [r["scenario_id"] for r in read_manifest(out)] == ["a0", "b0"]
    monkeypatch.undo()

    # Cluster slices, then merge: same manifest as the single run.
    for i in range(2):
        assert run_filter(files, str(tmp_path / f"part{i}"), part=(i, 2), skip_bad=True,
                          progress=False) is None
    merged = merge([tmp_path / "part1", tmp_path / "part0"], str(tmp_path / "merged"))
    assert merged == counts
    assert read_manifest(tmp_path / "merged", kept_only=False) == rows

    # A regenerated input shard is filtered again, the unchanged one is not.
    write_tfexample(files[0], [scene(0.1, [], sid="new")])
    calls = []
    real_filter_shard = filt.filter_shard
    monkeypatch.setattr(filt, "filter_shard", lambda f, *a: calls.append(f) or
                        real_filter_shard(f, *a))
    counts = run_filter(files, str(out), progress=False)
    assert calls == [files[0]] and counts["scenarios"] == 3
    assert [r["scenario_id"] for r in read_manifest(out, False)] == ["new", "b0", "b1"]


def test_manifest_errors(tmp_path):
    files = _shards(tmp_path)
    out = tmp_path / "o"
    run_filter(files[:1], str(out), progress=False)
    rows = read_manifest(out, kept_only=False)
    with pytest.raises(DataError, match="record 7: manifest points at a record"):
        list(iter_manifest_scenarios([{**rows[0], "record": 7}]))
    with pytest.raises(DataError, match="missing file"):
        list(iter_manifest_scenarios([{**rows[0], "file": str(tmp_path / "gone.tfrecord")}]))
    with pytest.raises(DataError, match="scenario id is 'a0', the manifest says 'zz'"):
        list(iter_manifest_scenarios([{**rows[0], "scenario_id": "zz"}]))
    (out / "manifest.jsonl").write_text('{"file": "x"}\n')
    with pytest.raises(DataError, match="line 1: missing field"):
        read_manifest(out)
    with pytest.raises(DataError, match="no filter manifest"):
        read_manifest(tmp_path / "nowhere")


def test_cli_filter_parallel_and_inspect(tmp_path, capsys):
    files = _shards(tmp_path)
    out = tmp_path / "cli"
    assert main(["filter", *files, "--out", str(out), "--workers", "2", "--skip-bad",
                 "--min-speed", "1.5", "--no-progress"]) == 0
    captured = capsys.readouterr()
    counts = json.loads(captured.out)
    assert counts["kept"] == 1 and counts["min_speed"] == 1.5
    assert "skipped 1 bad record(s)" in captured.err
    assert "record 2" in (out / "bad_records.jsonl").read_text()
    assert main(["filter", *files, "--out", str(tmp_path / "strict"), "--no-progress",
                 "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "record 2: unknown record format" in err
    assert main(["filter", "--merge", str(out), "--out", str(tmp_path / "m")]) == 0
    assert json.loads(capsys.readouterr().out)["min_speed"] == 1.5  # stored settings reused
    assert main(["inspect", files[0], "--limit", "1"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1
    line = json.loads(lines[0])
    assert line["scenario_id"] == "a0" and line["format"] == "tf_example"
    assert line["sdc_index"] == 0 and line["interactive"] and line["objects_of_interest"] == 1
    assert main(["inspect", files[1]]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "record 2: unknown record format" in err
    assert main(["filter", files[0], "--out", str(out), "--part", "2/2"]) == 2


@needs_womd
def test_bench_data_small(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "data", "--limit", "4", "--shards", "2", "--workers", "1",
                 "--samples", str(WOMD), "--out", str(out)]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    assert [(r["input"], r["what"], r["scenarios"]) for r in rows] == [
        ("tf_example", "read", 4), ("tf_example", "filter", 4),
        ("scenario_proto", "read", 1), ("scenario_proto", "filter", 1)]
    assert json.loads(out.read_text())["runs"] == rows


def test_iter_manifest_scenarios_groups_by_file(tmp_path):
    files = _shards(tmp_path)
    run_filter(files, str(tmp_path / "o"), skip_bad=True, progress=False)
    rows = read_manifest(tmp_path / "o", kept_only=False)
    shuffled = [rows[3], rows[0], rows[2], rows[1]]  # b1, a0, b0, a1
    got = [(e["scenario_id"], decode_scenario_id(s.scenario_id))
           for e, s in iter_manifest_scenarios(shuffled, None, chunk=1)]
    assert got == [("b0", "b0"), ("b1", "b1"), ("a0", "a0"), ("a1", "a1")]
