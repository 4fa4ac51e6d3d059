"""WOMD tf.Example <-> :class:`Scenario` (one unbatched scenario at its native sizes).

Keys follow WOMD's motion tf.Example: ``state/{past,current,future}/*`` stored object-major
(``[O, 10]``, ``[O, 1]``, ``[O, 80]``), ``roadgraph_samples/*`` (``R`` = 20,000 in v1.0/1.1, 30,000
in v1.2+; detected from the data), ``traffic_light_state/*`` stored time-major (``[T, L]``).
"""

from __future__ import annotations

import numpy as np

from igdrivsim.data.protos import example_class
from igdrivsim.data.scenario import (
    CURRENT_INDEX,
    NUM_STEPS,
    ObjectMetadata,
    Roadgraph,
    Scenario,
    TrafficLights,
    Trajectory,
    decode_scenario_id,
    empty_lights,
    read_scenario_id,
)
from igdrivsim.errors import DataError

PARTS = (("past", CURRENT_INDEX), ("current", 1), ("future", NUM_STEPS - CURRENT_INDEX - 1))
# our Trajectory field -> tf.Example state key suffix
STATE_KEYS = {"x": "x", "y": "y", "z": "z", "yaw": "bbox_yaw", "vel_x": "velocity_x",
              "vel_y": "velocity_y", "length": "length", "width": "width", "height": "height"}
# our TrafficLights field -> tf.Example key suffix
LIGHT_KEYS = {"state": "state", "lane_id": "id", "x": "x", "y": "y", "z": "z"}


def is_tfexample(example) -> bool:
    """Whether a parsed Example carries WOMD motion keys (used to auto-detect the format)."""
    feature = example.features.feature
    return "state/current/x" in feature or "roadgraph_samples/xyz" in feature


def _values(feature_map, key: str, size: int | None, dtype, required: bool = True):
    """The values of ``key`` as a NumPy array of ``dtype`` (``None`` if absent and optional)."""
    if key not in feature_map:
        if required:
            raise DataError("missing feature", key=key)
        return None
    feature = feature_map[key]
    kind = feature.WhichOneof("kind")
    if kind not in ("float_list", "int64_list"):
        raise DataError(f"expected a float or int64 list, found {kind}", key=key)
    values = np.asarray(getattr(feature, kind).value, dtype=np.float64 if kind == "float_list"
                        else np.int64)
    if size is not None and values.size != size:
        raise DataError(f"expected {size} values, found {values.size}", key=key)
    if kind == "float_list" and not np.isfinite(values).all():
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise DataError(f"non-finite value (NaN or inf) at flat index {bad}", key=key)
    return values.astype(dtype)


def decode_tfexample(data: bytes) -> Scenario:
    """Decode one serialized WOMD motion tf.Example into a :class:`Scenario` (native sizes); a
    missing, mis-shaped or non-finite feature or not exactly one SDC is a :class:`DataError`."""
    example = example_class().FromString(data)
    fm = example.features.feature
    if not is_tfexample(example):
        raise DataError("not a WOMD motion tf.Example (no state/ or roadgraph_samples/ keys)")
    num_objects = _values(fm, "state/current/x", None, np.float32).size

    def state(suffix: str, dtype) -> np.ndarray:
        parts = [_values(fm, f"state/{part}/{suffix}", num_objects * width, dtype)
                 .reshape(num_objects, width) for part, width in PARTS]
        return np.concatenate(parts, axis=1)

    valid = state("valid", np.int64) > 0
    trajectory = Trajectory(**{name: state(key, np.float32) for name, key in STATE_KEYS.items()},
                            valid=valid)
    flag = lambda key, required=True: _values(fm, key, num_objects, np.int64, required)
    is_sdc = flag("state/is_sdc") > 0
    if is_sdc.sum() != 1:
        raise DataError(f"expected exactly one SDC, found {int(is_sdc.sum())}", key="state/is_sdc")
    optional = {k: flag(f"state/{k}", False) for k in ("tracks_to_predict", "objects_of_interest")}
    metadata = ObjectMetadata(
        id=flag("state/id").astype(np.int32), object_type=flag("state/type").astype(np.int32),
        is_sdc=is_sdc, valid=valid.any(axis=1),
        **{k: np.zeros(num_objects, bool) if v is None else v > 0 for k, v in optional.items()})

    num_points = _values(fm, "roadgraph_samples/type", None, np.int32).size
    roadgraph = Roadgraph(
        xyz=_values(fm, "roadgraph_samples/xyz", 3 * num_points, np.float32).reshape(-1, 3),
        dir=_values(fm, "roadgraph_samples/dir", 3 * num_points, np.float32).reshape(-1, 3),
        type=_values(fm, "roadgraph_samples/type", num_points, np.int32),
        id=_values(fm, "roadgraph_samples/id", num_points, np.int32),
        valid=_values(fm, "roadgraph_samples/valid", num_points, np.int64) > 0,
    )
    return Scenario(trajectory=trajectory, metadata=metadata, roadgraph=roadgraph,
                    traffic_lights=_decode_lights(fm), scenario_id=_decode_id(fm))


def _decode_lights(fm) -> TrafficLights:
    current = _values(fm, "traffic_light_state/current/state", None, np.int32, required=False)
    num_lights = 0 if current is None else current.size

    def light(suffix: str, dtype) -> np.ndarray:  # [T, L] in the file -> [L, T]
        parts = [_values(fm, f"traffic_light_state/{part}/{suffix}", width * num_lights, dtype)
                 .reshape(width, num_lights) for part, width in PARTS]
        return np.concatenate(parts, axis=0).T.copy()

    if num_lights == 0:
        return empty_lights(0)
    fields = {name: light(key, np.int32 if name in ("state", "lane_id") else np.float32)
              for name, key in LIGHT_KEYS.items()}
    return TrafficLights(valid=light("valid", np.int64) > 0, **fields)


def _decode_id(fm) -> np.ndarray:
    if "scenario/id" not in fm:
        raise DataError("missing feature", key="scenario/id")
    values = fm["scenario/id"].bytes_list.value
    if len(values) != 1:
        raise DataError(f"expected 1 bytes value, found {len(values)}", key="scenario/id")
    return read_scenario_id(values[0], "scenario/id")


def encode_tfexample(scenario: Scenario) -> bytes:
    """Serialize one unbatched :class:`Scenario` as a WOMD motion tf.Example; decoding gives back
    identical arrays (``metadata.valid`` re-derived as "valid at some step")."""
    if scenario.batch_shape:
        raise ValueError(f"encode_tfexample takes one scenario, got batch {scenario.batch_shape}")
    example = example_class()()
    fm = example.features.feature

    def floats(key: str, a) -> None:
        fm[key].float_list.value.extend(np.asarray(a, np.float32).ravel().tolist())

    def ints(key: str, a) -> None:
        fm[key].int64_list.value.extend(np.asarray(a, np.int64).ravel().tolist())

    tr, md, tl = scenario.trajectory, scenario.metadata, scenario.traffic_lights
    num_objects = md.is_sdc.shape[-1]
    start = 0
    for part, width in PARTS:  # states object-major, lights time-major
        sl = slice(start, start + width)
        steps = np.arange(start, start + width, dtype=np.int64) * 100_000
        for name, key in STATE_KEYS.items():
            floats(f"state/{part}/{key}", np.asarray(getattr(tr, name))[:, sl])
        floats(f"state/{part}/speed", np.asarray(tr.speed)[:, sl])
        floats(f"state/{part}/vel_yaw",
               np.arctan2(np.asarray(tr.vel_y)[:, sl], np.asarray(tr.vel_x)[:, sl]))
        ints(f"state/{part}/valid", np.asarray(tr.valid)[:, sl])
        ints(f"state/{part}/timestamp_micros", np.broadcast_to(steps, (num_objects, width)))
        for name, key in LIGHT_KEYS.items():
            (ints if name in ("state", "lane_id") else floats)(
                f"traffic_light_state/{part}/{key}", np.asarray(getattr(tl, name))[:, sl].T)
        ints(f"traffic_light_state/{part}/valid", np.asarray(tl.valid)[:, sl].T)
        ints(f"traffic_light_state/{part}/timestamp_micros", steps)
        start += width
    # WOMD stores ids and types as floats; ids that float32 cannot hold exactly go as int64.
    (floats if np.all(np.abs(np.asarray(md.id)) < 2**24) else ints)("state/id", md.id)
    floats("state/type", md.object_type)
    for key in ("is_sdc", "tracks_to_predict", "objects_of_interest"):
        ints(f"state/{key}", getattr(md, key))

    for name in ("xyz", "dir", "type", "id", "valid"):
        (floats if name in ("xyz", "dir") else ints)(f"roadgraph_samples/{name}",
                                                       getattr(scenario.roadgraph, name))

    fm["scenario/id"].bytes_list.value.append(
        decode_scenario_id(scenario.scenario_id).encode("ascii"))
    # deterministic: a map's entries in key order, so the same scenario is the same bytes in any
    # process (protobuf otherwise writes them in hash order)
    return example.SerializeToString(deterministic=True)
