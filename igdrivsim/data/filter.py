"""The paper's scenario filter: keep scenarios where the SDC is interactive and actually drives
(docs/data.md, The paper's filter; thresholds in :class:`FilterConfig`).

**Interactive** (criterion ``paper``): the SDC's logged path intersects another object's,
regardless of time (exact 2-D test, touching counts); ``objects_of_interest``: WOMD's flag
instead. **Mean speed**: over the SDC's valid steps; 0 if never valid.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from dataclasses import asdict, dataclass

import numpy as np
from tqdm.auto import tqdm

from igdrivsim.data.manifest import COUNTS, MANIFEST, write_json, write_manifest
from igdrivsim.data.reader import ReadStats, as_paths, expand_paths, iter_file, pool_map
from igdrivsim.data.scenario import TYPE_VEHICLE, Scenario, as_ego, decode_scenario_id
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.io import atomic_path, read_json

CRITERIA = ("paper", "objects_of_interest")


@dataclass(frozen=True)
class FilterConfig:
    """Which scenarios to keep. Defaults are the paper's."""

    criterion: str = "paper"  # "paper" (geometric path intersection) or "objects_of_interest"
    min_speed: float = 0.7  # m/s, SDC mean speed over its valid steps

    def __post_init__(self):
        if self.criterion not in CRITERIA:
            raise ConfigError(f"unknown filter criterion {self.criterion!r}; "
                              f"choose one of {', '.join(CRITERIA)}")
        if not np.isfinite(self.min_speed) or self.min_speed < 0:
            raise ConfigError(f"min_speed must be a finite number >= 0, got {self.min_speed}")


def segments_intersect(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray
                       ) -> np.ndarray:
    """Whether segment ``p0-p1`` and segment ``q0-q1`` share a point; ``[..., 2]`` arrays broadcast.
    Orientation test plus bounding-box overlap (settles collinear and zero-length segments)."""
    p0, p1, q0, q1 = (np.asarray(a, np.float64) for a in (p0, p1, q0, q1))

    def side(a, b, c):  # sign of (b - a) x (c - a)
        return np.sign((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1])
                       - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))

    straddle = ((side(p0, p1, q0) * side(p0, p1, q1) <= 0)
                & (side(q0, q1, p0) * side(q0, q1, p1) <= 0))
    boxes = ((np.maximum(p0, p1) >= np.minimum(q0, q1))
             & (np.maximum(q0, q1) >= np.minimum(p0, p1))).all(-1)
    return straddle & boxes


def valid_xy(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """``(valid [O, T], xy [O, T, 2] float64)`` of one unbatched scenario (slot valid too)."""
    tr, md = scenario.trajectory, scenario.metadata
    valid = np.asarray(tr.valid, bool) & np.asarray(md.valid, bool)[:, None]
    return valid, np.stack([np.asarray(tr.x, np.float64), np.asarray(tr.y, np.float64)], -1)


def intersecting_objects(scenario: Scenario) -> np.ndarray:
    """Bool ``[O]``: which other objects' logged paths intersect the SDC's (unbatched scenario)."""
    is_sdc = np.asarray(scenario.metadata.is_sdc, bool)
    hits = np.zeros(is_sdc.shape[-1], bool)
    if scenario.batch_shape:
        raise ValueError(f"intersecting_objects takes one scenario, got {scenario.batch_shape}")
    if not is_sdc.any():
        return hits
    sdc = int(np.argmax(is_sdc))
    valid, xy = valid_xy(scenario)
    seg_ok = valid[:, :-1] & valid[:, 1:]  # path segments: between consecutive valid steps
    s0, s1 = xy[sdc, :-1][seg_ok[sdc]], xy[sdc, 1:][seg_ok[sdc]]
    if len(s0) == 0:
        return hits
    origin = s0[0]
    s0, s1, xy = s0 - origin, s1 - origin, xy - origin
    seg_ok[sdc] = False
    # Other objects' segments, keeping those whose bounding box meets the SDC path's box.
    owner, t = np.nonzero(seg_ok)
    q0, q1 = xy[owner, t], xy[owner, t + 1]
    qlo, qhi = np.minimum(q0, q1), np.maximum(q0, q1)
    slo, shi = np.minimum(s0, s1), np.maximum(s0, s1)
    near = (qlo <= shi.max(0)).all(-1) & (qhi >= slo.min(0)).all(-1)
    owner, q0, q1, qlo, qhi = owner[near], q0[near], q1[near], qlo[near], qhi[near]
    # Segment pairs whose boxes overlap, then the exact test on those only.
    i, j = np.nonzero(((slo[:, None] <= qhi[None]) & (shi[:, None] >= qlo[None])).all(-1))
    crossed = segments_intersect(s0[i], s1[i], q0[j], q1[j])
    hits[owner[j[crossed]]] = True
    return hits


def sdc_mean_speed(scenario: Scenario) -> float:
    """Mean speed (m/s) of the SDC over its valid steps; 0 when it is never valid."""
    tr, is_sdc = scenario.trajectory, np.asarray(scenario.metadata.is_sdc, bool)
    sdc = int(np.argmax(is_sdc))
    valid = np.asarray(tr.valid, bool)[sdc] & is_sdc.any()  # no SDC: never valid
    if not valid.any():
        return 0.0
    speed = np.hypot(np.asarray(tr.vel_x, np.float64)[sdc], np.asarray(tr.vel_y, np.float64)[sdc])
    return float(speed[valid].mean())


def scenario_stats(scenario: Scenario) -> dict:
    """What the filter decides on: ``scenario_id, sdc_mean_speed, interactive,
    objects_of_interest`` (number of flagged objects) for one unbatched scenario."""
    return {
        "scenario_id": decode_scenario_id(scenario.scenario_id),
        "sdc_mean_speed": round(sdc_mean_speed(scenario), 6),
        "interactive": bool(intersecting_objects(scenario).any()),
        "objects_of_interest": int(np.asarray(scenario.metadata.objects_of_interest).sum()),
    }


def keep(stats: dict, config: FilterConfig = FilterConfig()) -> bool:
    """Whether a scenario with these :func:`scenario_stats` passes the filter."""
    interactive = (bool(stats["interactive"]) if config.criterion == "paper"
                   else int(stats["objects_of_interest"]) > 0)
    return interactive and float(stats["sdc_mean_speed"]) >= config.min_speed


def count(entries: list[dict], config: FilterConfig, bad_records: int = 0) -> dict:
    """Counts per criterion over manifest entries (what ``counts.json`` holds)."""
    fast = [e for e in entries if e["sdc_mean_speed"] >= config.min_speed]
    return {
        "criterion": config.criterion,
        "min_speed": config.min_speed,
        "scenarios": len(entries),
        "bad_records": bad_records,
        "fast_enough": len(fast),
        "interactive": sum(bool(e["interactive"]) for e in entries),
        "objects_of_interest": sum(int(e["objects_of_interest"]) > 0 for e in entries),
        "interactive_and_fast": sum(bool(e["interactive"]) for e in fast),
        "objects_of_interest_and_fast": sum(int(e["objects_of_interest"]) > 0 for e in fast),
        "kept": sum(bool(e["kept"]) for e in entries),
    }


# --- the filter over sharded inputs: per-shard partial results, parts, merge ---------------

SHARDS_DIR, CONFIG_FILE, BAD_FILE = "shards", "filter_config.json", "bad_records.jsonl"


def parse_part(text: str | None) -> tuple[int, int] | None:
    """``"i/n"`` (0 <= i < n) -> ``(i, n)``: this run takes shards ``i, i + n, i + 2n, ...``."""
    if text is None:
        return None
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ConfigError(f"--part must look like i/n (e.g. 3/100), got {text!r}") from None
    if not 0 <= i < n:
        raise ConfigError(f"--part {text}: need 0 <= i < n")
    return i, n


def shard_result_path(out: str, file: str) -> str:
    """Where the partial result of input ``file`` goes (name + hash of its absolute path)."""
    digest = hashlib.sha1(os.path.abspath(file).encode()).hexdigest()[:10]
    return os.path.join(out, SHARDS_DIR, f"{os.path.basename(file)}.{digest}.json")


def ego_candidates(scenario: Scenario) -> np.ndarray:
    """Slots of the vehicles valid over the whole window: who may be the ego."""
    md = scenario.metadata
    valid = np.asarray(scenario.trajectory.valid, bool).all(axis=-1) & np.asarray(md.valid, bool)
    return np.flatnonzero(valid & (np.asarray(md.object_type) == TYPE_VEHICLE))


def ego_entries(scenario: Scenario) -> list[dict]:
    """:func:`scenario_stats` with each :func:`ego_candidates` vehicle as the ego, with ``ego``
    (its object id) and ``logged_sdc``; ``scenario_id`` stays the source scenario's."""
    md, sid = scenario.metadata, decode_scenario_id(scenario.scenario_id)
    out = []
    for slot in ego_candidates(scenario):
        row = scenario_stats(as_ego(scenario, int(slot)))
        out.append({**row, "scenario_id": sid, "ego": int(np.asarray(md.id)[slot]),
                    "logged_sdc": bool(np.asarray(md.is_sdc)[slot])})
    return out


def filter_shard(file: str, result_path: str, skip_bad: bool = False, egos: str = "sdc"
                 ) -> tuple[int, int]:
    """:func:`scenario_stats` of every record of ``file`` (``egos="all"``: :func:`ego_entries`),
    written atomically to ``result_path``; returns ``(scenarios, bad_records)``."""
    file = os.path.abspath(file)
    signature = _signature(file)  # before reading: a file changed meanwhile is redone next time
    stats = ReadStats()
    entries = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for rec in iter_file(file, caps=None, skip_bad=skip_bad, stats=stats):
            where = {"file": file, "record": rec.record}
            if egos == "all":
                entries += [{**where, **e} for e in ego_entries(rec.scenario)]
            else:
                entries.append({**where, **scenario_stats(rec.scenario)})
    bad = [{"file": f, "record": r, "error": msg} for f, r, msg in stats.skipped]
    mode = {} if egos == "sdc" else {"egos": egos}
    write_json(result_path, {"file": file, "entries": entries, "bad": bad, **signature, **mode})
    return len(entries), len(bad)


def _signature(file: str) -> dict:
    st = os.stat(file)
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _read_shard_result(path: str, file: str | None = None, egos: str | None = None
                       ) -> dict | None:
    """A finished partial result, or None (to redo) if it is absent, unreadable or (given
    ``file`` and ``egos``) made from another version of that file or for other egos."""
    result = read_json(path, {})
    if "entries" not in result or (egos is not None and result.get("egos", "sdc") != egos):
        return None
    try:
        if file is not None and any(result.get(k) != v for k, v in _signature(file).items()):
            return None
    except OSError:
        return None
    return result


def run_filter(inputs, out: str, config: FilterConfig = FilterConfig(), workers: int = 0,
               part: tuple[int, int] | None = None, skip_bad: bool = False,
               progress: bool = True, egos: str = "sdc") -> dict | None:
    """Filter the shards named by ``inputs`` into ``out`` (docs/data.md, The paper's filter), each
    shard's result kept in ``out/shards/`` once done (a rerun skips it); returns the counts, or with
    ``part=(i, n)`` does slice ``i`` of ``n`` only (joined by :func:`merge`) and returns None."""
    files = expand_paths(inputs)
    if part is not None:
        files = files[part[0]::part[1]]
    os.makedirs(os.path.join(out, SHARDS_DIR), exist_ok=True)
    resolved = {**asdict(config), "inputs": as_paths(inputs),
                "part": None if part is None else f"{part[0]}/{part[1]}", "skip_bad": skip_bad,
                **({} if egos == "sdc" else {"egos": egos})}
    name = CONFIG_FILE if part is None else f"filter_config.part-{part[0]}-of-{part[1]}.json"
    write_json(os.path.join(out, name), resolved)
    todo = [f for f in files if _read_shard_result(shard_result_path(out, f), f, egos) is None]
    scenarios = 0
    tasks = [(f, shard_result_path(out, f), skip_bad, egos) for f in todo]
    with tqdm(total=len(files), initial=len(files) - len(todo), desc="filter", unit="shard",
              disable=not progress) as bar:
        for done, _ in pool_map(filter_shard, tasks, min(workers, len(todo))):
            scenarios += done
            bar.update()
            bar.set_postfix(scenarios=scenarios)
    if part is not None:
        return None
    return _write_outputs(out, [shard_result_path(out, f) for f in files], config)


def _write_outputs(out: str, result_paths: list[str], config: FilterConfig) -> dict:
    entries, bad, seen = [], [], set()
    for path in result_paths:
        if (result := _read_shard_result(path)) is None:
            raise DataError("partial filter result missing or unreadable", file=path)
        if result["file"] in seen:
            continue
        seen.add(result["file"])
        entries += result["entries"]
        bad += result.get("bad", [])
    for e in entries:
        e["kept"] = keep(e, config)
    write_manifest(os.path.join(out, MANIFEST), entries)
    bad_path = os.path.join(out, BAD_FILE)
    if bad:
        with atomic_path(bad_path, "w") as f:
            f.writelines(json.dumps(b) + "\n" for b in bad)
    elif os.path.exists(bad_path):
        os.remove(bad_path)  # left from an earlier run over other inputs
    counts = count(entries, config, bad_records=len(bad))
    counts["files"] = len(seen)
    write_json(os.path.join(out, COUNTS), counts)
    return counts


def stored_config(dirs) -> FilterConfig | None:
    """The filter settings of the runs in ``dirs`` (None: none stored; ConfigError: they differ)."""
    found = set()
    for d in dirs:
        for name in sorted(os.listdir(d)) if os.path.isdir(d) else []:
            if name.startswith("filter_config") and name.endswith(".json"):
                path = os.path.join(d, name)
                c = read_json(path)
                try:
                    found.add((c["criterion"], float(c["min_speed"])))
                except (ValueError, TypeError, KeyError) as err:
                    raise DataError(f"unreadable filter settings ({type(err).__name__}: {err})",
                                    file=path) from err
    if len(found) > 1:
        raise ConfigError(f"the runs to merge used different filter settings: {sorted(found)}; "
                          "pass --criterion and --min-speed")
    return FilterConfig(*found.pop()) if found else None


def merge(dirs, out: str, config: FilterConfig | None = None) -> dict:
    """Join the per-shard results of the filter runs in ``dirs`` into ``out`` (entries sorted by
    file, then record); ``config=None``: the runs' own settings (else the paper's)."""
    dirs = as_paths(dirs)
    paths = []
    for d in dirs:
        shard_dir = os.path.join(d, SHARDS_DIR)
        if not os.path.isdir(shard_dir):
            raise DataError("not a filter output folder (no shards/ inside)", file=d)
        paths += [os.path.join(shard_dir, n) for n in os.listdir(shard_dir)
                  if n.endswith(".json") and not n.startswith(".")]
    config = config or stored_config(dirs) or FilterConfig()
    files = {}
    for p in paths:
        if (result := _read_shard_result(p)) is None or not isinstance(result.get("file"), str):
            raise DataError("partial filter result unreadable (corrupt JSON or no \"file\" / "
                            "\"entries\"); rerun the filter run that wrote it (it redoes "
                            "unreadable shards)", file=p)
        files.setdefault(result["file"], p)
    write_json(os.path.join(out, CONFIG_FILE), {**asdict(config), "merged": dirs})
    return _write_outputs(out, [files[f] for f in sorted(files)], config)
