"""Legacy MetaDrive pickles (inert type tags, refused smuggling), ``igdrivsim samples`` (fetch,
verify, reuse; no network: a fake wheel) and the real-log table. The public samples themselves
are checked when ``igdrivsim samples`` has put them in the cache folder."""

from __future__ import annotations

import enum
import hashlib
import io
import json
import os
import pickle
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from igdrivsim.data import samples
from igdrivsim.data import scenarionet as sn
from igdrivsim.data.scenario import NUM_STEPS, RG_CROSSWALK, RG_SPEED_BUMP, RG_STOP_SIGN
from igdrivsim.errors import DataError

LEGACY = {name: enum.Enum(name, {n: i for i, n in enumerate(members)}, module="__main__")
          for name, members in (
              ("AgentType", ("UNSET", "VEHICLE", "PEDESTRIAN", "CYCLIST", "OTHER")),
              ("RoadLineType", ("UNKNOWN", "BROKEN_SINGLE_WHITE", "SOLID_SINGLE_WHITE")),
              ("RoadEdgeType", ("UNKNOWN", "BOUNDARY", "MEDIAN")))}


def _legacy_bytes(monkeypatch, steps: int = 120) -> bytes:
    """A MetaDrive 0.2-style WOMD pickle, its tags pickled as ``__main__.<Enum>(code)``."""
    for name, cls in LEGACY.items():
        monkeypatch.setattr(sys.modules["__main__"], name, cls, raising=False)
    agent, line, edge = LEGACY["AgentType"], LEGACY["RoadLineType"], LEGACY["RoadEdgeType"]
    t = np.arange(steps) * 0.1
    x = 5.0 * t

    def state(y: float) -> np.ndarray:  # x, y, z, length, width, height, heading, vx, vy, valid
        return np.c_[x, np.full(steps, y), 0 * t, np.full(steps, 4.5), np.full(steps, 2.0),
                     np.ones(steps), 0 * t, np.full(steps, 5.0), 0 * t, np.ones(steps)]

    bump = {"polygon": np.array([[10, -1, 0], [12, -1, 0], [12, 1, 0], [10, 1, 0.0]])}
    bump["type"] = bump  # as MetaDrive 0.2 wrote it
    desc = {"id": "legacy0", "ts": list(t), "sdc_index": 7,
            "tracks": {7: {"type": agent.VEHICLE, "state": state(0.0)},
                       8: {"type": agent.PEDESTRIAN, "state": state(3.0)},
                       9: {"type": agent.UNSET, "state": state(-3.0)}},
            "dynamic_map_states": [{1: {"state": 6, "stop_point": [0.0, 0.0, 0.0]}}],
            "map": {1: {"type": "center_lane", "polyline": np.c_[x, 0 * x, 0 * x],
                        "left_boundaries": [{"type": line.SOLID_SINGLE_WHITE}]},
                    2: {"type": line.BROKEN_SINGLE_WHITE, "polyline": np.c_[x, 2 + 0 * x, 0 * x]},
                    3: {"type": edge.BOUNDARY, "polyline": np.c_[x, -4 + 0 * x, 0 * x]},
                    4: {"type": edge.MEDIAN, "polyline": np.c_[x[::-1], 4 + 0 * x, 0 * x]},
                    5: {"type": "stop_sign", "lanes": [1], "pos": [30.0, 1.0, 0.0]},
                    6: {"sign": "cross_walk", "polygon": bump["polygon"] + [10, 0, 0]},
                    7: bump}}
    data = pickle.dumps(desc, protocol=3)
    assert b"c__main__\nAgentType\n" in data  # the GLOBAL opcodes of the real legacy files
    return data


def test_legacy_pickle_loads_with_inert_tags(tmp_path, monkeypatch):
    path = tmp_path / "0.pkl"
    path.write_bytes(_legacy_bytes(monkeypatch))
    desc = sn.safe_load(path)
    assert desc["tracks"][7]["type"] == "VEHICLE" and type(desc["tracks"][7]["type"]) is str
    assert desc["map"][2]["type"] == "ROAD_LINE_BROKEN_SINGLE_WHITE"
    assert desc["map"][1]["left_boundaries"][0]["type"] == "ROAD_LINE_SOLID_SINGLE_WHITE"
    ((s, source),) = sn.read_file(path)
    assert source["first_step"] == 0  # 120 steps: one 91-step window
    assert s.trajectory.x.shape == (3, NUM_STEPS) and s.metadata.is_sdc.tolist() == [1, 0, 0]
    assert s.metadata.object_type.tolist() == [1, 2, 4] and s.metadata.id.tolist() == [7, 8, 9]
    assert s.trajectory.length[0, 0] == pytest.approx(4.5)
    types = set(np.asarray(s.roadgraph.type).tolist())
    assert {2, 6, 15, 16, RG_STOP_SIGN, RG_CROSSWALK, RG_SPEED_BUMP} <= types
    assert s.traffic_lights.state.shape[0] == 0  # MetaDrive 0.2 kept one step of them: dropped
    assert sn.source_dataset(path) == "WOMD"


def test_legacy_member_by_name_and_unknown_names():
    unpickler = sn.SafeUnpickler(io.BytesIO(b""), "f.pkl")
    assert unpickler.find_class("__main__", "RoadEdgeType.MEDIAN") == "ROAD_EDGE_MEDIAN"
    for module, name in (("__main__", "system"), ("__main__", "AgentType.__class__"),
                         ("metadrive.utils.waymo_utils.waymo_utils", "np"),
                         ("os", "AgentType")):
        with pytest.raises(DataError, match="refused to load class"):
            unpickler.find_class(module, name)


class _Evil:
    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_malicious_pickles_with_legacy_names_are_refused(tmp_path, monkeypatch):
    marker = tmp_path / "pwned"
    cmd = f"touch {marker}".encode()
    tag = b"\x80\x02c__main__\nAgentType\n"
    crafted = {
        "tag called with a command": tag + b"X" + len(cmd).to_bytes(4, "little") + cmd
        + b"\x85R.",
        "tag called with two codes": tag + b"K\x01K\x02\x86R.",
        "state set on a tag": tag + b"K\x01\x85R}U\x01aK\x01sb.",
        "os.system beside a tag": tag + b"K\x01\x85R0cos\nsystem\n" + b"X"
        + len(cmd).to_bytes(4, "little") + cmd + b"\x85R.",
        "__main__.system": b"\x80\x02c__main__\nsystem\nX" + len(cmd).to_bytes(4, "little")
        + cmd + b"\x85R.",
    }
    legacy = pickle.loads(_legacy_bytes(monkeypatch)) | {"extra": _Evil(str(marker))}
    crafted["__reduce__ inside a legacy file"] = pickle.dumps(legacy, protocol=3)
    for what, data in crafted.items():
        path = tmp_path / "evil.pkl"
        path.write_bytes(data)
        with pytest.raises(DataError) as err:
            sn.safe_load(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value), what
        assert not marker.exists(), what


def test_argoverse_replay_log_is_refused_with_a_reason(tmp_path):
    path = tmp_path / "argo.pkl"
    path.write_bytes(pickle.dumps(({"00": {"init_pos": np.zeros(2), "traj": {}}}, "PIT")))
    with pytest.raises(DataError, match="Argoverse replay log"):
        sn.read_file(path)


def _fake_wheel(tmp_path, monkeypatch) -> str:
    """A two-scenario wheel, made the expected one (``FILES``, ``WHEEL_SHA256``)."""
    wheel = tmp_path / "fake.whl"
    files = {}
    with zipfile.ZipFile(wheel, "w") as zf:
        for i in range(2):
            data = f"scenario {i}".encode()
            zf.writestr(f"metadrive/assets/waymo/{i}.pkl", data)
            files[f"metadrive/assets/waymo/{i}.pkl"] = (f"{i}.pkl",
                                                        hashlib.sha256(data).hexdigest(), "id")
    monkeypatch.setattr(samples, "FILES", files)
    monkeypatch.setattr(samples, "WHEEL_SHA256", samples.sha256(wheel))
    return str(wheel)


def test_samples_fetch_verify_and_reuse_offline(tmp_path, monkeypatch):
    wheel = _fake_wheel(tmp_path, monkeypatch)
    out = tmp_path / "cache"
    paths, fetched = samples.fetch(out, wheel)
    assert fetched and [p.name for p in paths] == ["0.pkl", "1.pkl"]
    assert json.loads((out / samples.RECORD).read_text())["terms"] == samples.TERMS

    def no_network(*_a, **_k):
        raise AssertionError("pip called although the files are there")

    monkeypatch.setattr(samples, "download_wheel", no_network)
    assert samples.fetch(out) == (paths, False)
    paths[1].write_bytes(b"tampered")  # a changed file is fetched again
    assert samples.verified(out) is None
    assert samples.fetch(out, wheel)[1]
    digest, files = samples.WHEEL_SHA256, samples.FILES
    monkeypatch.setattr(samples, "WHEEL_SHA256", "0" * 64)
    with pytest.raises(DataError, match="sha256"):
        samples.fetch(tmp_path / "other", wheel)
    monkeypatch.setattr(samples, "WHEEL_SHA256", digest)
    bad = dict(files, **{"metadrive/assets/waymo/1.pkl": ("1.pkl", "0" * 64, "id")})
    monkeypatch.setattr(samples, "FILES", bad)
    with pytest.raises(DataError, match="waymo/1.pkl"):
        samples.fetch(tmp_path / "other", wheel)


def test_a_samples_folder_names_its_scenario_files(tmp_path, monkeypatch):
    """``--data`` given the folder of ``igdrivsim samples`` reads the scenarios under it, not
    its record file."""
    from igdrivsim.data import expand_paths

    paths, _ = samples.fetch(tmp_path / "cache", _fake_wheel(tmp_path, monkeypatch))
    assert expand_paths(tmp_path / "cache") == [str(p) for p in paths]


def test_samples_command_prints_place_and_terms(tmp_path, monkeypatch, capsys):
    from igdrivsim.cli import main

    wheel = _fake_wheel(tmp_path, monkeypatch)
    assert main(["samples", "--out", str(tmp_path / "s"), "--wheel", wheel]) == 0
    out = capsys.readouterr().out
    assert str(tmp_path / "s" / "womd") in out and "Non-Commercial" in out
    assert main(["samples", "--out", str(tmp_path / "s"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["fetched"] is False
    assert main(["samples", "--out", str(tmp_path / "t"), "--wheel", "/no/such.whl"]) == 2


def test_default_cache_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert samples.default_dir() == tmp_path / "igdrivsim" / "samples"
    assert samples.find_samples() is None


def test_real_log_table_states_n_beside_every_number():
    from igdrivsim.report.real_logs import real_log_table, real_logs_latex, real_logs_markdown

    def frame(n: int, methods) -> pd.DataFrame:
        rows = [dict(setting=s, method=m, seed=seed, scenario_id=f"s{i}", log_divergence=1.0 + i,
                     overlap_steps=0.1, offroad_steps=0.2, max_log_divergence=2.0, overlap=0,
                     offroad=1) for s, m in methods for seed in (0, 1) for i in range(n)]
        return pd.DataFrame(rows)

    learned = [("full", "bc"), ("circular_r4", "bc")]
    real = frame(6, [*learned, ("none", "expert")])
    table = real_log_table(real, frame(4, [*learned, ("full", "bc_rl")]))
    assert table.method.tolist() == ["bc", "bc", "expert"]  # only what ran on real logs
    md = real_logs_markdown(table, "3 logs", "synthetic")
    rows = [ln for ln in md.splitlines() if ln.startswith("| ") and "N=" in ln]
    assert len(rows) == 3 and all(c.strip() == "--" or "(N=" in c
                                  for r in rows for c in r.split("|")[3:-1])
    assert "3.50 (N=6)" in md and "2.50 (N=4)" in md and "20.0 (N=6)" in md
    assert r"\label{tab:real-logs}" in real_logs_latex(table, "3 logs", "synthetic")


def test_real_log_table_measures_each_driver_against_constant_velocity():
    """On the same real scenarios: the difference from constant velocity, an interval that
    holds it, and the smallest difference the scenarios detect, in the table and the summary."""
    from igdrivsim.report.real_logs import real_log_table, real_logs_markdown, real_logs_summary

    rows = [dict(setting="full", method="bc", seed=seed, scenario_id=f"s{i}",
                 log_divergence=5.0 + i % 2 + 0.1 * seed, overlap_steps=0.0, offroad_steps=0.0,
                 max_log_divergence=9.0, overlap=0, offroad=0) for seed in (0, 1)
            for i in range(8)]
    rows += [dict(setting="none", method="constant_velocity", seed=0, scenario_id=f"s{i}",
                  log_divergence=4.0 + i % 2, overlap_steps=0.0, offroad_steps=0.0,
                  max_log_divergence=9.0, overlap=0, offroad=0) for i in range(8)]
    table = real_log_table(pd.DataFrame(rows)).set_index("method")
    bc = table.loc["bc"]
    assert bc.real_vs_cv_diff == pytest.approx(1.05)
    assert bc.real_vs_cv_lo <= 1.05 <= bc.real_vs_cv_hi and bc.real_vs_cv_mde > 0
    assert pd.isna(table.loc["constant_velocity", "real_vs_cv_diff"])
    md = real_logs_markdown(table.reset_index(), "logs", "synthetic")
    assert "| +1.05 [" in md and "MDE" in md
    assert "detect only differences of" in real_logs_summary(table.reset_index())


def test_real_log_summary_says_who_drifts_farther_than_constant_velocity(tmp_path):
    """The abstract's sentence is computed from the table and written for the PDF."""
    from igdrivsim.report.real_logs import real_logs_summary, write_numbers

    table = pd.DataFrame([
        dict(setting="full", method="bc", real_log_divergence=6.5, real_n=6,
             validation_log_divergence=5.3, validation_n=323),
        dict(setting="circular_r4", method="bc", real_log_divergence=9.0, real_n=6,
             validation_log_divergence=6.4, validation_n=323),
        dict(setting="full", method="bc_rl", real_log_divergence=4.0, real_n=6,
             validation_log_divergence=5.4, validation_n=323),
        dict(setting="none", method="constant_velocity", real_log_divergence=4.87, real_n=6,
             validation_log_divergence=8.01, validation_n=323)])
    for key in ("offroad", "overlap"):
        for source in ("real", "validation"):
            table[f"{source}_{key}"] = 1.0
    sentence = real_logs_summary(table)
    assert sentence.startswith("On 6 real scenarios, 2 of 3 learned")
    assert "4.87 m for constant velocity" in sentence and "BC 6.50-9.00 m" in sentence
    farther = table.assign(real_log_divergence=[6.5, 9.0, 5.0, 4.87])
    assert "every learned driver drifts farther" in real_logs_summary(farther)
    assert real_logs_summary(table[table.method != "constant_velocity"]) is None
    write_numbers(table, tmp_path)
    tex = (tmp_path / "real_logs_summary.tex").read_text()
    assert r"Table~\ref{tab:real-logs}" in tex and "4.87~m" in tex


def test_pipeline_skips_real_logs_without_samples(tmp_path, capsys):
    from igdrivsim.pipeline.profiles import PROFILES
    from igdrivsim.pipeline.stages import Pipeline

    pipe = Pipeline(PROFILES["smoke"], tmp_path / "work", tmp_path / "paper")
    pipe.run_real_logs()
    assert "real_logs: no real samples" in capsys.readouterr().err
    assert not (tmp_path / "work" / "evals_real").exists()


def test_reproduce_checks_samples_before_any_stage(tmp_path, monkeypatch):
    from igdrivsim.errors import ConfigError
    from igdrivsim.pipeline.cli import resolve_samples

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert resolve_samples(None) == ()
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="igdrivsim samples --out"):
        resolve_samples(str(tmp_path / "empty"))
    with pytest.raises(DataError, match="NOPE"):
        resolve_samples(str(tmp_path / "NOPE"))
    path = tmp_path / "mine" / "0.pkl"  # any real data location is taken as it is
    path.parent.mkdir()
    path.write_bytes(_legacy_bytes(monkeypatch))
    assert resolve_samples(str(path.parent)) == (str(path.parent),)
    other = tmp_path / "more" / "1.pkl"  # several locations: each once, in order
    other.parent.mkdir()
    other.write_bytes(_legacy_bytes(monkeypatch))
    assert resolve_samples([str(path.parent), str(other.parent), str(path.parent)]) == (
        str(path.parent), str(other.parent))


def test_render_says_whether_the_scene_is_synthetic_or_real(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from igdrivsim.data.scenario import encode_scenario_id
    from igdrivsim.observation.commands import scene_source

    fake = SimpleNamespace(scenario_id=encode_scenario_id("syn0v00000003"))
    assert scene_source("x.tfrecord", fake).startswith("synthetic scenario syn0v00000003")
    path = tmp_path / "0.pkl"
    path.write_bytes(_legacy_bytes(monkeypatch))
    fake = SimpleNamespace(scenario_id=encode_scenario_id("legacy0"))
    assert scene_source(str(path), fake) == "real WOMD scenario legacy0 (0.pkl)"


needs_cache = pytest.mark.skipif(samples.find_samples() is None,
                                 reason="public samples not fetched (igdrivsim samples)")


@needs_cache
def test_public_samples_replay_within_5_cm(capsys):
    from igdrivsim.cli import main

    assert main(["replay", str(samples.find_samples()), "--json", "--no-progress"]) == 0
    lines = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    assert len(lines) == 6 and {d["source_id"] for d in lines} == {
        sid for _, _, sid in samples.FILES.values()}
    assert all(d["replay_max_log_divergence"] < 0.05 for d in lines)


def test_every_real_location_is_read_with_each_ego_s_source_log():
    """Several real locations at once, every vehicle as the ego: each scenario's origin names
    its source log (a window of a ScenarioNet log: the log, not the window) and whether it is
    the logged SDC."""
    from igdrivsim.data import Capacities
    from igdrivsim.data.source import load_scenarios

    shared = Path(__file__).resolve().parents[2] / "shared" / "data"
    log = shared / "scenarionet" / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"
    json_dir = shared / "gpudrive"
    if not log.is_file() or not json_dir.is_dir():
        pytest.skip(f"real samples absent ({shared}): licences keep them out of the repository")
    scenarios, origins = load_scenarios([str(log), str(json_dir)], Capacities(), egos="all")
    assert len(origins) == int(scenarios.scenario_id.shape[0])
    by_source = {}
    for o in origins:
        by_source.setdefault(o["source"], []).append(o)
    windows = {o["scenario_id"].split("#")[0] for o in by_source["eb4b91b10ca94ff2"]}
    assert windows and all(w.startswith("eb4b91b10ca94ff2_") for w in windows)  # window, log
    assert {"db4edc9bd0c9d18c", "bada21415c031740"} <= set(by_source)
    assert any(o["logged_sdc"] for o in origins) and not all(o["logged_sdc"] for o in origins)
