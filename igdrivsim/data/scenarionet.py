"""ScenarioNet scenario descriptions (pickled dicts) -> :class:`Scenario` windows.

Files are loaded with :class:`SafeUnpickler` (NumPy arrays, builtin containers and the inert
:class:`LegacyTag` stand-ins of old MetaDrive enum tags only: nothing in a file can run code).
Logs are resampled to 10 Hz if needed and cut into consecutive 91-step windows, each one
scenario; maps without road edges (nuScenes) get them from the union of the lane polygons
(:func:`union_boundary`). Field mapping, legacy pickles and windows: docs/scenarionet.md.
"""

from __future__ import annotations

import hashlib
import os
import pickle
from collections import defaultdict
from typing import Any

import jax
import numpy as np

from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    DT,
    LIGHT_STATE_NAMES,
    NUM_STEPS,
    RG_CROSSWALK,
    RG_ROAD_EDGE_BOUNDARY,
    RG_ROAD_EDGE_MEDIAN,
    RG_ROAD_EDGE_TYPES,
    RG_SPEED_BUMP,
    RG_STOP_SIGN,
    SCENARIO_ID_BYTES,
    TYPE_CYCLIST,
    TYPE_NAMES,
    TYPE_OTHER,
    TYPE_PEDESTRIAN,
    TYPE_VEHICLE,
    ObjectMetadata,
    Roadgraph,
    Scenario,
    TrafficLights,
    Trajectory,
    encode_scenario_id,
)
from igdrivsim.data.womd_proto import MAX_SPACING, roadgraph_from_polylines, subdivide
from igdrivsim.errors import DataError

FORMAT_SCENARIONET = "scenarionet"
SUMMARY_FILE, MAPPING_FILE = "dataset_summary.pkl", "dataset_mapping.pkl"
PICKLE_SUFFIXES = (".pkl", ".pickle")
PROBE = 0.2  # m: a derived road-edge sample is on the boundary when this far right is no lane

_ALLOWED = {
    ("builtins", n) for n in ("dict", "list", "tuple", "set", "frozenset", "str", "bytes",
                              "bytearray", "int", "float", "complex", "bool")
} | {("collections", "OrderedDict"), ("collections", "defaultdict"),
     ("numpy", "ndarray"), ("numpy", "dtype")} | {
    (f"numpy.{core}.multiarray", n) for core in ("core", "_core") for n in ("_reconstruct",
                                                                             "scalar")
}

OBJECT_TYPES = {"VEHICLE": TYPE_VEHICLE, "PEDESTRIAN": TYPE_PEDESTRIAN,
                "CYCLIST": TYPE_CYCLIST}  # anything else (cones, barriers, ...): TYPE_OTHER
LANE_TYPES = {"LANE_FREEWAY": 1, "LANE_SURFACE_STREET": 2, "LANE_BIKE_LANE": 3, "LANE_UNKNOWN": 2}
ROAD_LINE_TYPES = {f"ROAD_LINE_{n}": 5 + i for i, n in enumerate((
    "UNKNOWN", "BROKEN_SINGLE_WHITE", "SOLID_SINGLE_WHITE", "SOLID_DOUBLE_WHITE",
    "BROKEN_SINGLE_YELLOW", "BROKEN_DOUBLE_YELLOW", "SOLID_SINGLE_YELLOW", "SOLID_DOUBLE_YELLOW",
    "PASSING_DOUBLE_YELLOW"))}
ROAD_EDGE_TYPES = {"ROAD_EDGE_BOUNDARY": RG_ROAD_EDGE_BOUNDARY,
                   "ROAD_EDGE_MEDIAN": RG_ROAD_EDGE_MEDIAN,
                   "ROAD_EDGE_UNKNOWN": RG_ROAD_EDGE_BOUNDARY,
                   "ROAD_EDGE_SIDEWALK": RG_ROAD_EDGE_BOUNDARY}
POLYLINE_TYPES = {**LANE_TYPES, **ROAD_LINE_TYPES, **ROAD_EDGE_TYPES}
POLYGON_TYPES = {"CROSSWALK": RG_CROSSWALK, "SPEED_BUMP": RG_SPEED_BUMP}
# WOMD TrafficSignalLaneState codes; MetaDrive's TRAFFIC_LIGHT_* names are used for nuPlan.
LIGHT_STATES = {**{f"LANE_STATE_{n}": i for i, n in enumerate(LIGHT_STATE_NAMES)},
                "TRAFFIC_LIGHT_UNKNOWN": 0, "TRAFFIC_LIGHT_RED": 4, "TRAFFIC_LIGHT_YELLOW": 5,
                "TRAFFIC_LIGHT_GREEN": 6}


# Type tags of older MetaDrive / ScenarioNet exports (MetaDrive 0.2's WOMD pickles store
# ``__main__.AgentType(1)``, ``RoadLineType(2)``, ...): enum classes named by these modules, each
# replaced by an inert stand-in that turns a WOMD enum code into our name (a plain ``str``).
LEGACY_MODULES = ("__main__", "metadrive.utils.waymo_utils.waymo_utils",
                  "metadrive.utils.waymo_utils.waymo_type")
LEGACY_TAGS: dict[str, tuple[str, ...]] = {
    "AgentType": TYPE_NAMES,
    "RoadLineType": tuple(ROAD_LINE_TYPES),
    "RoadEdgeType": ("ROAD_EDGE_UNKNOWN", "ROAD_EDGE_BOUNDARY", "ROAD_EDGE_MEDIAN"),
    "LaneType": ("LANE_UNKNOWN", "LANE_FREEWAY", "LANE_SURFACE_STREET", "LANE_BIKE_LANE"),
    "TrafficLightState": tuple(n for n in LIGHT_STATES if n.startswith("LANE_STATE_")),
}
_TAG_PREFIXES = ("ROAD_LINE_", "ROAD_EDGE_", "LANE_STATE_", "LANE_")


def _member(name: str) -> str:
    """An enum member's own name: ``ROAD_LINE_SOLID_SINGLE_WHITE`` -> ``SOLID_SINGLE_WHITE``."""
    return next((name[len(p):] for p in _TAG_PREFIXES if name.startswith(p)), name)


class LegacyTag:
    """Inert stand-in for an old export's enum class: ``Tag(code)`` returns our name (a str) for
    one int among the enum's codes, else a :class:`DataError`; it cannot run code."""

    __slots__ = ("file", "kind", "names")

    def __init__(self, kind: str, file: str):
        self.kind, self.names, self.file = kind, LEGACY_TAGS[kind], file

    def __call__(self, *args: object) -> str:
        if len(args) == 1 and type(args[0]) is int and 0 <= args[0] < len(self.names):
            return self.names[args[0]]
        shown = ", ".join(repr(a)[:40] for a in args)
        raise DataError(f"refused {self.kind}({shown}): a legacy type tag takes one of the codes "
                        f"0..{len(self.names) - 1}", file=self.file)


class SafeUnpickler(pickle.Unpickler):
    """Unpickler that rebuilds only NumPy arrays/dtypes/scalars, builtin containers and the
    legacy type tags (:class:`LegacyTag`, never the classes themselves)."""

    def __init__(self, file, name: str):
        super().__init__(file)
        self.name = name

    def find_class(self, module: str, name: str):
        if (module, name) in _ALLOWED:
            return super().find_class(module, name)
        if module in LEGACY_MODULES:
            kind, _, member = name.partition(".")
            if kind in LEGACY_TAGS and not member:
                return LegacyTag(kind, self.name)
            for full in LEGACY_TAGS.get(kind, ()):  # an enum member pickled by name
                if member and member in (full, _member(full)):
                    return full
        raise DataError(f"refused to load class {module}.{name} (a ScenarioNet file holds only "
                        "NumPy arrays, builtin containers and legacy type tags)", file=self.name)


def safe_load(path: str | os.PathLike) -> Any:
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            return SafeUnpickler(f, path).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError,
            IndexError, KeyError, MemoryError) as err:
        raise DataError(f"not a readable pickle: {type(err).__name__}: {err}", file=path) from None


def is_scenarionet_file(path: str) -> bool:
    """A pickle that is a scenario description (by suffix; the summary/mapping files are not)."""
    base = os.path.basename(path)
    return base.endswith(PICKLE_SUFFIXES) and base not in (SUMMARY_FILE, MAPPING_FILE)


def dataset_files(folder: str) -> list[str] | None:
    """Scenario files of a ScenarioNet dataset folder (``dataset_summary.pkl`` names them,
    ``dataset_mapping.pkl`` gives their sub-folders), or None if ``folder`` is not one."""
    summary_path = os.path.join(folder, SUMMARY_FILE)
    if not os.path.isfile(summary_path):
        return None
    summary = safe_load(summary_path)
    mapping_path = os.path.join(folder, MAPPING_FILE)
    mapping = safe_load(mapping_path) if os.path.isfile(mapping_path) else {}
    if not isinstance(summary, dict) or not isinstance(mapping, dict):
        raise DataError("expected a dict of scenario files", file=summary_path)
    files = []
    for name in sorted(summary):
        path = os.path.normpath(os.path.join(folder, str(mapping.get(name, "")), str(name)))
        if not os.path.isfile(path):
            raise DataError(f"dataset lists {name!r}, not found at {path}", file=summary_path)
        files.append(path)
    return files


def _key_ids(keys: list) -> dict:
    """int32 ids for string keys: the keys themselves if all are small integers, else 0..n-1."""
    try:
        ints = [int(k) for k in keys]
        if all(0 <= i < 2**31 for i in ints) and len(set(ints)) == len(ints):
            return dict(zip(keys, ints, strict=True))
    except (TypeError, ValueError):
        pass
    return {k: i for i, k in enumerate(keys)}


def _array(value, shape_tail: tuple[int, ...], key: str) -> np.ndarray:
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise DataError("not a numeric array", key=key) from None
    if shape_tail == (1,) and a.ndim == 1:
        a = a[:, None]
    if a.ndim != 1 + len(shape_tail) or any(
            s != -1 and a.shape[1 + i] < s for i, s in enumerate(shape_tail)):
        raise DataError(f"shape {a.shape}, expected [T, {shape_tail}]", key=key)
    return np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)


def _timestep(desc: dict) -> float:
    meta = desc.get("metadata", {})
    ts = meta.get("ts")
    if ts is not None and len(ts) >= 2:
        return float(np.median(np.diff(np.asarray(ts, np.float64))))
    if meta.get("sample_rate"):
        return float(meta["sample_rate"])
    return DT


def _resample(a: np.ndarray, src_t: np.ndarray, dst_t: np.ndarray, angle: bool = False):
    """Linear interpolation along axis 1 of ``a [O, T, ...]`` (angles unwrapped first)."""
    if angle:
        a = np.unwrap(a, axis=1)
    idx = np.clip(np.searchsorted(src_t, dst_t, side="right") - 1, 0, len(src_t) - 2)
    w = ((dst_t - src_t[idx]) / (src_t[idx + 1] - src_t[idx])).reshape(
        (1, -1) + (1,) * (a.ndim - 2))
    out = a[:, idx] * (1 - w) + a[:, idx + 1] * w
    return np.arctan2(np.sin(out), np.cos(out)) if angle else out


def _decode_tracks(desc: dict) -> dict[str, np.ndarray]:
    """All tracks at their native length: arrays ``[O, T]`` (``xyz``/``vel`` ``[O, T, k]``)."""
    tracks = desc.get("tracks")
    if not isinstance(tracks, dict) or not tracks:
        raise DataError("no tracks", key="tracks")
    length = int(desc.get("length") or 0)
    keys = list(tracks)
    rows: dict[str, list] = defaultdict(list)
    types = []
    for k in keys:
        track = tracks[k]
        state = track.get("state", {}) if isinstance(track, dict) else {}
        where = f"tracks/{k}/state"
        try:
            pos = _array(state["position"], (2,), f"{where}/position")
            t = length or pos.shape[0]
            xyz = np.zeros((t, 3))
            xyz[:, : min(3, pos.shape[1])] = pos[:t, :3]
            rows["xyz"].append(xyz)
            rows["yaw"].append(_array(state["heading"], (), f"{where}/heading").reshape(-1)[:t])
            rows["vel"].append(_array(state["velocity"], (2,), f"{where}/velocity")[:t, :2])
            for size in ("length", "width", "height"):
                rows[size].append(_array(state[size], (1,), f"{where}/{size}")[:t, 0]
                                  if size in state else np.zeros(t))
            rows["valid"].append(np.asarray(state["valid"]).reshape(-1)[:t].astype(bool))
        except KeyError as err:
            raise DataError(f"missing {err.args[0]!r}", key=where) from None
        types.append(OBJECT_TYPES.get(str(track.get("type", "")).upper(), TYPE_OTHER))
    lengths = {len(v) for rs in rows.values() for v in rs}
    if len(lengths) != 1:
        raise DataError(f"tracks of different lengths {sorted(lengths)}", key="tracks")
    out = {k: np.stack(v) for k, v in rows.items()}
    out["type"] = np.asarray(types, np.int32)
    # a vehicle box wider than long has length and width swapped (nuScenes' ego in ScenarioNet)
    n = np.maximum(out["valid"].sum(1), 1)
    swap = (out["type"] == TYPE_VEHICLE) & (
        (out["width"] * out["valid"]).sum(1) / n > (out["length"] * out["valid"]).sum(1) / n)
    out["length"][swap], out["width"][swap] = out["width"][swap], out["length"][swap].copy()
    out["id"] = np.asarray(list(_key_ids(keys).values()), np.int64).astype(np.int32)
    meta = desc.get("metadata", {})
    sdc = str(meta.get("sdc_id", ""))
    str_keys = [str(k) for k in keys]
    if sdc not in str_keys:
        raise DataError(f"sdc_id {sdc!r} is not a track", key="metadata/sdc_id")
    out["is_sdc"] = np.asarray([k == sdc for k in str_keys])
    out["interest"] = np.isin(str_keys, [str(k) for k in meta.get("objects_of_interest") or []])
    out["predict"] = np.isin(str_keys, [str(k) for k in (meta.get("tracks_to_predict") or {})])
    return out


def _points(value, key: str, drop_z: bool) -> np.ndarray:
    try:
        a = np.asarray(value, np.float64).reshape(-1, np.shape(value)[-1])
    except (TypeError, ValueError, IndexError):
        raise DataError("not a numeric point array", key=key) from None
    if a.shape[-1] < 2 or not np.isfinite(a).all():
        raise DataError(f"bad points of shape {a.shape}", key=key)
    dims = 2 if drop_z else min(3, a.shape[1])
    xyz = np.zeros((len(a), 3))
    xyz[:, :dims] = a[:, :dims]
    return xyz


def union_boundary(polygons: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boundary of the union of polygons as sampled, oriented polylines ``(xy [N, 2], dir [N, 2],
    polyline [N])``: each ring counter-clockwise (interior on the left), sampled every
    ``MAX_SPACING`` m; a sample is kept when the point ``PROBE`` m to its right is in no polygon."""
    from matplotlib.path import Path  # heavy: only for maps without road edges

    rings, bbox = [], []
    for p in polygons:
        p = np.asarray(p, np.float64)[:, :2]
        if len(p) > 1 and np.allclose(p[0], p[-1]):
            p = p[:-1]
        if len(p) < 3:
            continue
        area = np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
        if abs(area) < 1e-6:
            continue
        rings.append(p if area > 0 else p[::-1])
        bbox.append(np.r_[p.min(0), p.max(0)])
    if not rings:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64)
    starts = np.concatenate(rings)
    ring_of = np.repeat(np.arange(len(rings)), [len(p) for p in rings])
    segs = np.concatenate([np.roll(p, -1, axis=0) - p for p in rings])  # each ring closed
    lens = np.linalg.norm(segs, axis=1)
    ok = lens > 1e-9
    xy, src = subdivide(starts[ok], segs[ok], MAX_SPACING)
    d, ring_of = segs[ok][src] / lens[ok][src, None], ring_of[ok][src]
    outside = xy + PROBE * np.stack([d[:, 1], -d[:, 0]], -1)  # right of dir
    covered = np.zeros(len(xy), bool)
    bbox = np.asarray(bbox)
    for ring, (x0, y0, x1, y1) in zip(rings, bbox, strict=True):
        near = ~covered & (outside[:, 0] >= x0) & (outside[:, 0] <= x1) & (
            outside[:, 1] >= y0) & (outside[:, 1] <= y1)
        if near.any():
            idx = np.flatnonzero(near)
            covered[idx[Path(ring).contains_points(outside[idx])]] = True
    keep = ~covered
    # a new polyline starts at each kept sample whose predecessor (same ring) was dropped
    prev_kept = np.r_[False, keep[:-1]] & np.r_[False, ring_of[1:] == ring_of[:-1]]
    poly = np.cumsum(keep & ~prev_kept) - 1
    return xy[keep], d[keep], poly[keep]


def _decode_map(desc: dict) -> tuple[Roadgraph, dict]:
    """Roadgraph at native size and the map-feature-key -> id mapping."""
    features = desc.get("map_features") or {}
    drop_z = str(desc.get("metadata", {}).get("dataset", "")).lower() == "nuscenes"
    ids = _key_ids(list(features))
    xyz, types, pids, lane_polygons = [], [], [], []
    for k, f in features.items():
        if not isinstance(f, dict):
            continue
        kind = str(f.get("type", "")).upper()
        where = f"map_features/{k}"
        if kind in LANE_TYPES and f.get("polygon") is not None:
            lane_polygons.append(_points(f["polygon"], f"{where}/polygon", True))
        if kind == "STOP_SIGN" and f.get("position") is not None:
            pts, rg_type = _points(f["position"], f"{where}/position", drop_z), RG_STOP_SIGN
        elif kind in POLYLINE_TYPES or kind in POLYGON_TYPES:
            field = "polyline" if kind in POLYLINE_TYPES else "polygon"
            if f.get(field) is None or not len(f[field]):
                continue
            pts = _points(f[field], f"{where}/{field}", drop_z)
            rg_type = (POLYLINE_TYPES | POLYGON_TYPES)[kind]
            if kind in ROAD_LINE_TYPES and len(pts) >= 4 and np.allclose(pts[0], pts[-1]):
                lane_polygons.append(pts)  # a closed outline: nuScenes' drivable area
        else:  # driveways, drivable-area outlines without a type we know: skipped
            continue
        xyz.append(pts)
        types.append(rg_type)
        pids.append(ids[k])
    rg = roadgraph_from_polylines(xyz, types, pids)
    if not any(t in RG_ROAD_EDGE_TYPES for t in types) and lane_polygons:
        bxy, bdir, bpoly = union_boundary(lane_polygons)
        base = int(max(ids.values(), default=-1)) + 1
        flat = lambda a: np.c_[a, np.zeros(len(a))].astype(np.float32)
        edges = Roadgraph(xyz=flat(bxy), dir=flat(bdir),
                          type=np.full(len(bxy), RG_ROAD_EDGE_BOUNDARY, np.int32),
                          id=(base + bpoly).astype(np.int32), valid=np.ones(len(bxy), bool))
        rg = jax.tree.map(lambda *parts: np.concatenate(parts), rg, edges)
    return rg, ids


def _decode_lights(desc: dict, map_ids: dict, length: int) -> dict[str, np.ndarray]:
    lights = [x for x in (desc.get("dynamic_map_states") or {}).values() if isinstance(x, dict)]
    n = len(lights)
    out = {"state": np.zeros((n, length), np.int32), "valid": np.zeros((n, length), bool),
           "lane_id": np.full((n, length), -1, np.int32), "xyz": np.zeros((n, length, 3))}
    for i, light in enumerate(lights):
        seq = (light.get("state") or {}).get("object_state") or []
        for t, s in enumerate(seq[:length]):
            if s is not None:
                out["state"][i, t], out["valid"][i, t] = LIGHT_STATES.get(str(s).upper(), 0), True
        lane = light.get("lane")
        out["lane_id"][i, out["valid"][i]] = map_ids.get(lane, map_ids.get(str(lane), -1))
        if light.get("stop_point") is not None:
            p = np.asarray(light["stop_point"], np.float64).reshape(-1)
            out["xyz"][i, :, : min(3, len(p))] = p[:3]
    return out


def window_id(source_id: str, first_step: int, windows: int) -> str:
    """Scenario id of a window: the source id, suffixed ``_<first_step>`` when the log has
    several windows; hashed down to fit ``SCENARIO_ID_BYTES`` ASCII bytes."""
    sid = source_id if windows == 1 else f"{source_id}_{first_step}"
    sid = sid.encode("ascii", "replace").decode("ascii")
    if len(sid) > SCENARIO_ID_BYTES:
        sid = f"{sid[: SCENARIO_ID_BYTES - 9]}-{hashlib.sha1(sid.encode()).hexdigest()[:8]}"
    return sid


def is_legacy_description(desc: Any) -> bool:
    """MetaDrive 0.2's WOMD export (``sdc_index``, ``map``, ``[T, 10]`` states) or its 2022-10
    successor (``sdc_track_index``, ``map_features``): no ``metadata``."""
    return (isinstance(desc, dict) and "tracks" in desc and "metadata" not in desc
            and ("sdc_index" in desc or "sdc_track_index" in desc))


def _legacy_state(state: Any, key: str) -> dict:
    if isinstance(state, dict):  # 2022-10: position, size [T, 3], heading / valid [T, 1]
        out = dict(state)
        if "size" in out:
            size = _array(out.pop("size"), (3,), f"{key}/size")
            out["length"], out["width"], out["height"] = size[:, 0], size[:, 1], size[:, 2]
        return out
    a = _array(state, (10,), key)  # x, y, z, length, width, height, heading, vx, vy, valid
    return {"position": a[:, 0:3], "length": a[:, 3], "width": a[:, 4], "height": a[:, 5],
            "heading": a[:, 6], "velocity": a[:, 7:9], "valid": a[:, 9] > 0.5}


def _legacy_feature(f: Any) -> dict | None:
    """A legacy map feature in ScenarioNet's form (``None``: not one we read)."""
    if not isinstance(f, dict):
        return None
    kind = f.get("type")
    if kind == "center_lane":  # the lane's WOMD type was not exported
        return {"type": "LANE_UNKNOWN", "polyline": f.get("polyline")}
    if kind == "stop_sign":
        return {"type": "STOP_SIGN", "position": f.get("pos", f.get("position"))}
    if f.get("sign") == "cross_walk":
        return {"type": "CROSSWALK", "polygon": f.get("polygon")}
    if isinstance(kind, dict) and "polygon" in f:  # the exporter stored the dict as its type
        return {"type": "SPEED_BUMP", "polygon": f.get("polygon")}
    if isinstance(kind, str):  # legacy tags (ROAD_LINE_*, ROAD_EDGE_*) and ScenarioNet names
        return {**f, "type": kind}
    return None


def legacy_description(desc: dict) -> dict:
    """An old MetaDrive WOMD export as a ScenarioNet description (field mapping:
    docs/scenarionet.md). Its traffic lights are dropped: MetaDrive 0.2 kept one step of them."""
    sdc = desc.get("sdc_track_index", desc.get("sdc_index"))
    tracks = {}
    for k, track in (desc.get("tracks") or {}).items():
        if not isinstance(track, dict) or "state" not in track:
            raise DataError("expected a dict with 'type' and 'state'", key=f"tracks/{k}")
        tracks[k] = {"type": str(track.get("type", "OTHER")),
                     "state": _legacy_state(track["state"], f"tracks/{k}/state")}
    features = desc.get("map_features", desc.get("map")) or {}
    if not isinstance(features, dict):
        raise DataError("expected a dict of map features", key="map")
    feats = {k: g for k, f in features.items() if (g := _legacy_feature(f)) is not None}
    sid = str(desc.get("id", ""))
    return {"id": sid, "version": str(desc.get("version", "metadrive-0.2")),
            "length": len(next(iter(tracks.values()))["state"]["position"]) if tracks else 0,
            "metadata": {"scenario_id": sid, "sdc_id": str(sdc), "ts": desc.get("ts"),
                         "dataset": "waymo", "coordinate": "waymo"},
            "tracks": tracks, "dynamic_map_states": {}, "map_features": feats}


def decode_description(desc: Any) -> list[tuple[Scenario, dict]]:
    """A ScenarioNet scenario dict (or a legacy MetaDrive export) as its 91-step windows, each
    with its source ``{"source_id", "first_step"}``."""
    if is_legacy_description(desc):
        desc = legacy_description(desc)
    if (isinstance(desc, tuple) and len(desc) == 2 and isinstance(desc[0], dict)
            and all(isinstance(v, dict) and "traj" in v for v in desc[0].values())):
        raise DataError("a MetaDrive Argoverse replay log (actor positions only: no map, object "
                        "sizes, types or ego), not a scenario description (docs/scenarionet.md)")
    if not isinstance(desc, dict) or "tracks" not in desc or "metadata" not in desc:
        raise DataError("not a ScenarioNet scenario description (a dict with 'tracks' and "
                        "'metadata')")
    meta = desc["metadata"]
    coordinate = str(meta.get("coordinate", "right-handed")).lower()
    if coordinate not in ("right-handed", "waymo"):
        raise DataError(f"coordinate system {coordinate!r} is not supported (only ScenarioNet's "
                        "right-handed dataset exports: 'right-handed', 'waymo')",
                        key="metadata/coordinate")
    source_id = str(meta.get("scenario_id") or meta.get("id") or desc.get("id") or "")
    tr = _decode_tracks(desc)
    length = tr["xyz"].shape[1]
    dt = _timestep(desc)
    if not 0.001 < dt < 10:
        raise DataError(f"bad timestep {dt} s", key="metadata/ts")
    if abs(dt - DT) > 0.01:  # resample to 10 Hz
        src = np.arange(length) * dt
        dst = np.arange(int(np.floor(src[-1] / DT + 1e-6)) + 1) * DT
        for k in ("xyz", "vel", "length", "width", "height", "yaw"):
            tr[k] = _resample(tr[k], src, dst, angle=k == "yaw")
        tr["valid"] = _resample(tr["valid"].astype(np.float64), src, dst) > 1 - 1e-6  # both valid
        light_src = np.clip(np.round(dst / dt).astype(np.int64), 0, length - 1)
        length = len(dst)
    else:
        light_src = np.arange(length)
    roadgraph, map_ids = _decode_map(desc)
    lights = {k: v[:, light_src]
              for k, v in _decode_lights(desc, map_ids, int(light_src[-1]) + 1).items()}
    if length <= CURRENT_INDEX:
        raise DataError(f"log has {length} steps at 10 Hz, needs > {CURRENT_INDEX}", key="length")
    starts = list(range(0, max(length - NUM_STEPS, 0) + 1, NUM_STEPS))  # consecutive windows
    return [(_window(tr, lights, roadgraph, s, window_id(source_id, s, len(starts))),
             {"source_id": source_id, "first_step": s}) for s in starts]


def _window(tr: dict, lights: dict, roadgraph: Roadgraph, start: int, sid: str) -> Scenario:
    t = slice(start, start + NUM_STEPS)

    def cut(a: np.ndarray, fill=0) -> np.ndarray:
        a = a[:, t]
        missing = NUM_STEPS - a.shape[1]
        if missing > 0:  # a short log: the end is padding
            pad = np.full((a.shape[0], missing) + a.shape[2:], fill, a.dtype)
            a = np.concatenate([a, pad], axis=1)
        return a

    valid = cut(tr["valid"], False)
    if not valid[tr["is_sdc"], CURRENT_INDEX].any():
        raise DataError(f"the SDC is not valid at the current step of window {start}", key="tracks")
    keep = valid.any(axis=1) | tr["is_sdc"]
    f32 = lambda a: cut(a)[keep].astype(np.float32)
    xyz, vel = f32(tr["xyz"]), f32(tr["vel"])
    trajectory = Trajectory(
        x=xyz[..., 0], y=xyz[..., 1], z=xyz[..., 2], yaw=f32(tr["yaw"]),
        vel_x=vel[..., 0], vel_y=vel[..., 1], length=f32(tr["length"]),
        width=f32(tr["width"]), height=f32(tr["height"]), valid=valid[keep])
    metadata = ObjectMetadata(
        id=tr["id"][keep], object_type=tr["type"][keep], is_sdc=tr["is_sdc"][keep],
        tracks_to_predict=tr["predict"][keep], objects_of_interest=tr["interest"][keep],
        valid=valid[keep].any(axis=1))
    lv = cut(lights["valid"], False)
    lkeep = lv.any(axis=1)
    lxyz = cut(lights["xyz"])[lkeep].astype(np.float32)
    traffic_lights = TrafficLights(
        state=cut(lights["state"])[lkeep], valid=lv[lkeep],
        lane_id=cut(lights["lane_id"], -1)[lkeep], x=lxyz[..., 0], y=lxyz[..., 1], z=lxyz[..., 2])
    return Scenario(trajectory=trajectory, metadata=metadata, roadgraph=roadgraph,
                    traffic_lights=traffic_lights, scenario_id=encode_scenario_id(sid))


DATASET_NAMES = {"waymo": "WOMD", "womd": "WOMD", "nuscenes": "nuScenes", "nuplan": "nuPlan",
                 "av2": "Argoverse 2", "argoverse2": "Argoverse 2", "lyft": "Lyft"}


def source_dataset(path: str | os.PathLike) -> str | None:
    """The dataset a scenario file comes from (``WOMD``, ``nuScenes``, ...), None if unsaid."""
    desc = safe_load(path)
    if is_legacy_description(desc):
        return "WOMD"
    meta = desc.get("metadata") if isinstance(desc, dict) else None
    name = str(meta.get("dataset", "")) if isinstance(meta, dict) else ""
    return DATASET_NAMES.get(name.lower(), name or None)


def read_file(path: str | os.PathLike) -> list[tuple[Scenario, dict]]:
    """The windows of one ScenarioNet ``.pkl`` file (native sizes)."""
    path = os.fspath(path)
    desc = safe_load(path)
    try:
        return decode_description(desc)
    except DataError as err:
        raise DataError(err.problem, file=path, key=err.key) from None

