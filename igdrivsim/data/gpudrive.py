"""GPUDrive / PufferDrive JSON scenarios -> :class:`Scenario` (one file, one scenario, native
sizes), as GPUDrive's converter (``data_utils/process_waymo_files.py`` of Emerge-Lab/gpudrive)
writes them. Field mapping (objects, roads, traffic lights, metadata): docs/data.md.
"""

from __future__ import annotations

import json
import os

import numpy as np

from igdrivsim.data.scenario import (
    LIGHT_STATE_NAMES,
    NUM_STEPS,
    RG_CROSSWALK,
    RG_LANE_SURFACE_STREET,
    RG_ROAD_EDGE_BOUNDARY,
    RG_SPEED_BUMP,
    RG_STOP_SIGN,
    TYPE_NAMES,
    ObjectMetadata,
    Roadgraph,
    Scenario,
    TrafficLights,
    Trajectory,
    empty_lights,
    object_flags,
    read_scenario_id,
)
from igdrivsim.data.womd_proto import roadgraph_from_polylines
from igdrivsim.errors import DataError

FORMAT_GPUDRIVE = "gpudrive_json"
INVALID = -10000.0  # what the converter writes in every field of an invalid step
OBJECT_TYPES = {name.lower(): code for code, name in enumerate(TYPE_NAMES)}
# coarse road ``type`` -> tf.Example code, when a road has no ``map_element_id``
COARSE_TYPES = {"lane": RG_LANE_SURFACE_STREET, "road_line": 5, "road_edge": RG_ROAD_EDGE_BOUNDARY,
                "stop_sign": RG_STOP_SIGN, "crosswalk": RG_CROSSWALK, "speed_bump": RG_SPEED_BUMP}
LIGHT_STATES = {name.lower(): code for code, name in enumerate(LIGHT_STATE_NAMES)}


def is_gpudrive_file(path: str) -> bool:
    """A ``.json`` file that opens with a JSON object (cheap: the first bytes only)."""
    if not path.endswith(".json") or not os.path.isfile(path):
        return False
    with open(path, "rb") as f:
        return f.read(64).lstrip().startswith(b"{")


def _get(obj, key: str, where: str, kind=None):
    at = f"{where}.{key}" if where else key
    if not isinstance(obj, dict) or key not in obj:
        raise DataError(f"missing key {key!r}", key=at)
    if kind is not None and not isinstance(obj[key], kind):
        raise DataError(f"expected {kind.__name__ if isinstance(kind, type) else 'a number'}, "
                        f"got {type(obj[key]).__name__}", key=at)
    return obj[key]


def _xyz(points, where: str, dims: str = "xyz") -> np.ndarray:
    try:
        return np.array([[p[c] for c in dims] for p in points], np.float64).reshape(-1, len(dims))
    except (KeyError, TypeError, ValueError) as err:
        raise DataError(f"expected points {{{', '.join(dims)}}} ({type(err).__name__}: {err})",
                        key=where) from None


def _decode_objects(objects: list) -> tuple[Trajectory, np.ndarray, np.ndarray]:
    num = len(objects)
    f = np.full((9, num, NUM_STEPS), -1.0, np.float32)  # x y z yaw vx vy length width height
    valid = np.zeros((num, NUM_STEPS), bool)
    ids, types = np.zeros(num, np.int32), np.zeros(num, np.int32)
    for i, obj in enumerate(objects):
        w = f"objects[{i}]"
        pos = _xyz(_get(obj, "position", w, list), f"{w}.position")
        vel = _xyz(_get(obj, "velocity", w, list), f"{w}.velocity", "xy")
        yaw = np.asarray(_get(obj, "heading", w, list), np.float64)
        ok = np.asarray(_get(obj, "valid", w, list), bool)
        for key, a in (("position", pos), ("velocity", vel), ("heading", yaw), ("valid", ok)):
            if len(a) != NUM_STEPS:
                raise DataError(f"{len(a)} steps, expected {NUM_STEPS}", key=f"{w}.{key}")
        rows = np.concatenate([pos, yaw[:, None], vel], axis=1)
        if not np.isfinite(rows[ok]).all() or (rows[ok] == INVALID).all(axis=1).any():
            raise DataError("a valid step holds a non-finite or invalid (-10000) value",
                            key=f"{w}.position")
        f[:6, i][:, ok] = rows[ok].T
        for k, key in enumerate(("length", "width", "height")):
            f[6 + k, i][ok] = float(_get(obj, key, w, (int, float)))
        valid[i] = ok
        ids[i] = int(_get(obj, "id", w, int))
        kind = _get(obj, "type", w, str)
        if kind not in OBJECT_TYPES:
            raise DataError(f"unknown object type {kind!r}; known: {', '.join(OBJECT_TYPES)}",
                            key=f"{w}.type")
        types[i] = OBJECT_TYPES[kind]
    return Trajectory(*f, valid=valid), ids, types


def road_code(road: dict, where: str) -> int | None:
    """The tf.Example roadgraph code of one road, None for a type we do not keep (driveway)."""
    code = road.get("map_element_id") if isinstance(road, dict) else None
    if isinstance(code, int) and 0 <= code < 20 and code != 4:
        return code
    if code is None:
        return COARSE_TYPES.get(_get(road, "type", where, str))
    return None  # 20: driveway; -1: unknown


def _decode_roads(roads: list) -> Roadgraph:
    xyz, types, ids = [], [], []
    for i, road in enumerate(roads):
        w = f"roads[{i}]"
        if (code := road_code(road, w)) is None:
            continue
        pts = _xyz(_get(road, "geometry", w, list), f"{w}.geometry")
        if not len(pts):
            continue
        if not np.isfinite(pts).all():
            raise DataError("non-finite map point", key=f"{w}.geometry")
        xyz.append(pts)
        types.append(code)
        ids.append(int(road.get("id", i)))
    return roadgraph_from_polylines(xyz, types, ids)


def _decode_lights(tl_states) -> TrafficLights:
    if not isinstance(tl_states, dict):
        raise DataError(f"expected an object keyed by lane id, got {type(tl_states).__name__}",
                        key="tl_states")
    out = empty_lights(len(tl_states))
    for slot, (lane, tl) in enumerate(tl_states.items()):
        w = f"tl_states.{lane}"
        steps = _get(tl, "time_index", w, list)
        names = _get(tl, "state", w, list)
        coords = [_get(tl, c, w, list) for c in "xyz"]
        if any(len(a) != len(steps) for a in (names, *coords)):
            raise DataError("state, x, y, z and time_index differ in length", key=w)
        for k, t in enumerate(steps):
            if not isinstance(t, int) or not 0 <= t < NUM_STEPS:
                raise DataError(f"time index {t!r} outside 0..{NUM_STEPS - 1}",
                                key=f"{w}.time_index")
            if names[k] not in LIGHT_STATES:
                raise DataError(f"unknown light state {names[k]!r}", key=f"{w}.state")
            out.state[slot, t], out.valid[slot, t] = LIGHT_STATES[names[k]], True
            out.lane_id[slot, t] = int(lane)
            out.x[slot, t], out.y[slot, t], out.z[slot, t] = (float(c[k]) for c in coords)
    return out


def decode_gpudrive(desc: dict) -> Scenario:
    """Decode one parsed GPUDrive JSON scenario (raises :class:`DataError` naming the key)."""
    if not isinstance(desc, dict):
        raise DataError(f"expected a JSON object, got {type(desc).__name__}")
    objects = _get(desc, "objects", "", list)
    if not objects:
        raise DataError("no objects", key="objects")
    trajectory, ids, types = _decode_objects(objects)
    meta = _get(desc, "metadata", "", dict)
    sdc = _get(meta, "sdc_track_index", "metadata", int)
    if not 0 <= sdc < len(objects):
        raise DataError(f"sdc_track_index is {sdc} with {len(objects)} objects",
                        key="metadata.sdc_track_index")
    predict = [_get(req, "track_index", f"metadata.tracks_to_predict[{k}]", int)
               for k, req in enumerate(_get(meta, "tracks_to_predict", "metadata", list))]
    interest = _get(meta, "objects_of_interest", "metadata", list)
    metadata = ObjectMetadata(id=ids, object_type=types, valid=trajectory.valid.any(axis=1),
                              **object_flags(ids, sdc, predict, interest))
    sid = read_scenario_id(_get(desc, "scenario_id", "", str), "scenario_id")
    return Scenario(trajectory=trajectory, metadata=metadata,
                    roadgraph=_decode_roads(_get(desc, "roads", "", list)),
                    traffic_lights=_decode_lights(desc.get("tl_states", {})), scenario_id=sid)


def read_file(path: str | os.PathLike) -> Scenario:
    """The scenario of one GPUDrive JSON file; a malformed one: a DataError naming file and key."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            desc = json.load(f)
    except OSError as err:
        raise DataError(f"cannot open: {err.strerror}", file=path) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DataError(f"not valid JSON ({err})", file=path) from None
    try:
        return decode_gpudrive(desc)
    except DataError as err:
        raise DataError(err.problem, file=path, key=err.key) from None
    except (TypeError, ValueError, KeyError, AttributeError) as err:
        raise DataError(f"malformed scenario ({type(err).__name__}: {err})", file=path) from None
