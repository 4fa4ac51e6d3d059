"""WOMD Scenario protobuf -> :class:`Scenario` (one unbatched scenario at its native sizes).

Tracks become trajectory rows (one per track, in file order). Map features become roadgraph
points with the tf.Example type codes: lane centres 1-3 (``LaneCenter.type``), road lines 5-13
(``RoadLine.type + 5``), road edges 14-16 (``RoadEdge.type + 14``), stop signs 17 (one point),
crosswalks 18 and speed bumps 19 (closed polygons). Driveways have no tf.Example type and are
skipped. Polylines keep their vertices and segments longer than ``MAX_SPACING`` are subdivided;
``dir`` is the unit vector to the next point of the polyline (zero at its end), so road edges keep
WOMD's orientation (road interior on the left). Traffic lights get one slot per controlled lane,
in order of first appearance.
"""

from __future__ import annotations

import numpy as np

from igdrivsim.data.protos import scenario_class
from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    NUM_STEPS,
    RG_CROSSWALK,
    RG_ROAD_EDGE_UNKNOWN,
    RG_SPEED_BUMP,
    RG_STOP_SIGN,
    ObjectMetadata,
    Roadgraph,
    Scenario,
    TrafficLights,
    Trajectory,
    empty_lights,
    object_flags,
    read_scenario_id,
)
from igdrivsim.errors import DataError

# a line feature's tf.Example type: its own type plus the offset of its kind
TYPE_OFFSETS = {"lane": 0, "road_line": 5, "road_edge": RG_ROAD_EDGE_UNKNOWN}
POLYGON_TYPES = {"crosswalk": RG_CROSSWALK, "speed_bump": RG_SPEED_BUMP}
MAX_SPACING = 0.5  # metres; WOMD's roadgraph sampling resolution


def is_scenario_proto(message) -> bool:
    """Whether a parsed Scenario message looks like a WOMD scenario (used for auto-detection)."""
    return len(message.tracks) > 0 and message.HasField("scenario_id")


def decode_scenario_proto(data: bytes | object) -> Scenario:
    """Decode a serialized (or parsed) WOMD Scenario protobuf into a :class:`Scenario`."""
    msg = scenario_class().FromString(data) if isinstance(data, bytes | bytearray) else data
    if not is_scenario_proto(msg):
        raise DataError("not a WOMD Scenario protobuf (no tracks or no scenario_id)")
    current = msg.current_time_index if msg.HasField("current_time_index") else CURRENT_INDEX
    if current != CURRENT_INDEX:
        raise DataError(f"current_time_index is {current}, expected {CURRENT_INDEX}",
                        key="current_time_index")
    trajectory, metadata = _decode_tracks(msg)
    sid = read_scenario_id(msg.scenario_id, "scenario_id")
    return Scenario(trajectory=trajectory, metadata=metadata,
                    roadgraph=_decode_map(msg.map_features),
                    traffic_lights=_decode_lights(msg.dynamic_map_states), scenario_id=sid)


def _decode_tracks(msg) -> tuple[Trajectory, ObjectMetadata]:
    num = len(msg.tracks)
    cols = ("center_x", "center_y", "center_z", "heading", "velocity_x", "velocity_y", "length",
            "width", "height", "valid")
    values = np.zeros((len(cols), num, NUM_STEPS), np.float64)
    rows, lengths = [], []
    for i, track in enumerate(msg.tracks):
        if len(track.states) > NUM_STEPS:
            raise DataError(f"track {i} has {len(track.states)} states, expected <= {NUM_STEPS}",
                            key="tracks.states")
        lengths.append(len(track.states))  # short tracks (test split) stay invalid-padded
        rows += [tuple(getattr(s, c) for c in cols) for s in track.states]
    if rows:
        lengths = np.asarray(lengths)
        track_of = np.repeat(np.arange(num), lengths)
        step_of = np.arange(len(rows)) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        values[:, track_of, step_of] = np.asarray(rows, np.float64).T
    valid = values[-1] > 0
    if not np.isfinite(values[:, valid]).all():
        bad = int(np.argwhere(~np.isfinite(values[:, valid]).all(axis=0))[0, 0])
        raise DataError(f"non-finite value (NaN or inf) in a valid state (#{bad})",
                        key="tracks.states")
    f = values[:-1].astype(np.float32)
    f[:, ~valid] = np.where(np.isfinite(f[:, ~valid]), f[:, ~valid], -1.0)
    trajectory = Trajectory(*f, valid=valid)  # f: the Trajectory fields in order
    if not msg.HasField("sdc_track_index") or not 0 <= msg.sdc_track_index < num:
        found = msg.sdc_track_index if msg.HasField("sdc_track_index") else "none"
        raise DataError(f"no SDC: sdc_track_index is {found} with {num} tracks",
                        key="sdc_track_index")
    ids = np.array([t.id for t in msg.tracks], np.int32)
    metadata = ObjectMetadata(
        id=ids, object_type=np.array([t.object_type for t in msg.tracks], np.int32),
        **object_flags(ids, msg.sdc_track_index, [r.track_index for r in msg.tracks_to_predict],
                       msg.objects_of_interest), valid=valid.any(axis=1))
    return trajectory, metadata


def subdivide(starts: np.ndarray, segments: np.ndarray, max_spacing: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Evenly spaced points on each segment ``starts[k] + [0, 1) * segments[k]``, pieces at most
    ``max_spacing`` long (2-D length): ``(points, index of each point's segment)``."""
    length = np.linalg.norm(segments[:, :2], axis=1)
    pieces = np.maximum(1, np.ceil(length / max_spacing - 1e-3)).astype(np.int64)
    source = np.repeat(np.arange(len(starts)), pieces)
    first = np.repeat(np.cumsum(pieces) - pieces, pieces)
    frac = ((np.arange(len(source)) - first) / pieces[source])[:, None]
    return starts[source] + frac * segments[source], source


def roadgraph_from_polylines(xyz: list[np.ndarray], types: list[int], ids: list[int]
                             ) -> Roadgraph:
    """The roadgraph of polylines ``xyz[i]`` ``[V_i, 3]`` of type ``types[i]``, id ``ids[i]``
    (polygons closed), vertices kept and segments longer than :data:`MAX_SPACING` (2-D length)
    subdivided evenly; ``dir`` as in the module docstring: one place for every reader's map."""
    if not xyz:
        z = np.zeros((0, 3), np.float32)
        return Roadgraph(xyz=z, dir=z, type=np.zeros(0, np.int32), id=np.zeros(0, np.int32),
                         valid=np.zeros(0, bool))
    xyz = [np.concatenate([p, p[:1]]) if t in POLYGON_TYPES.values() else p
           for p, t in zip(xyz, types, strict=True)]
    poly = np.repeat(np.arange(len(xyz)), [len(p) for p in xyz])
    points = np.concatenate(xyz)
    seg = np.zeros_like(points)  # vertex k starts a segment of its polyline, or none (zero)
    seg[:-1] = np.where((poly[1:] == poly[:-1])[:, None], np.diff(points, axis=0), 0.0)
    if not (np.linalg.norm(seg[:, :2], axis=1) / MAX_SPACING - 1e-3 <= 1).all():
        points, source = subdivide(points, seg, MAX_SPACING)
        poly = poly[source]
    step = np.diff(points, axis=0)
    norm = np.linalg.norm(step, axis=1, keepdims=True)
    direction = np.zeros_like(points)
    direction[:-1] = np.where((poly[1:] == poly[:-1])[:, None] & (norm > 0),
                              step / np.maximum(norm, 1e-12), 0.0)
    return Roadgraph(xyz=points.astype(np.float32), dir=direction.astype(np.float32),
                     type=np.asarray(types, np.int32)[poly],
                     id=np.asarray(ids, np.int64)[poly].astype(np.int32),
                     valid=np.ones(len(points), bool))


def _decode_map(features) -> Roadgraph:
    xyz, types, ids = [], [], []
    for feature in features:
        kind = feature.WhichOneof("feature_data")
        if kind in TYPE_OFFSETS:
            rg_type = getattr(feature, kind).type + TYPE_OFFSETS[kind]
            pts = getattr(feature, kind).polyline
        elif kind in POLYGON_TYPES:
            rg_type, pts = POLYGON_TYPES[kind], getattr(feature, kind).polygon
        elif kind == "stop_sign":
            rg_type, pts = RG_STOP_SIGN, [feature.stop_sign.position]
        else:  # driveway or unset: no tf.Example type
            continue
        if not pts:
            continue
        points = np.array([(p.x, p.y, p.z) for p in pts], np.float64)
        if not np.isfinite(points).all():
            raise DataError(f"non-finite map point in feature {feature.id}", key="map_features")
        xyz.append(points)
        types.append(rg_type)
        ids.append(feature.id)
    return roadgraph_from_polylines(xyz, types, ids)


def _decode_lights(dynamic_states) -> TrafficLights:
    if len(dynamic_states) > NUM_STEPS:
        raise DataError(f"{len(dynamic_states)} dynamic map states, expected <= {NUM_STEPS}",
                        key="dynamic_map_states")
    slots: dict[int, int] = {}
    rows = []
    for t, dms in enumerate(dynamic_states):
        for ls in dms.lane_states:
            slot = slots.setdefault(ls.lane, len(slots))
            p = ls.stop_point
            rows.append((slot, t, ls.state, p.x, p.y, p.z))
    tl = empty_lights(len(slots))
    if rows:
        lanes = np.array(list(slots), np.int64)
        slot, t, s = (np.array([r[k] for r in rows], np.int64) for k in range(3))
        tl.state[slot, t], tl.valid[slot, t], tl.lane_id[slot, t] = s, True, lanes[slot]
        tl.x[slot, t], tl.y[slot, t], tl.z[slot, t] = np.array([r[3:] for r in rows]).T
    return tl
