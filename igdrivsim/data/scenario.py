"""The scenario data model: one immutable pytree per WOMD scenario.

Every array may carry arbitrary leading batch dimensions ``...``; the trailing dimensions are
fixed by :class:`Capacities`. Padding slots are marked invalid, never silently cut. Arrays are
NumPy on the host (readers, generator, filter) and become JAX arrays when passed to ``jit``.

Axis conventions (WOMD / Waymax): objects ``O``, time ``T`` (91 steps at 10 Hz: 10 past, 1
current at index 10, 80 future), roadgraph points ``R``, traffic lights ``L``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass

import jax
import numpy as np
from flax import struct

from igdrivsim.errors import DataError

NUM_STEPS = 91  # 9.1 s at 10 Hz
CURRENT_INDEX = 10  # index of the "current" step; steps 0..10 are the warm-up
DT = 0.1  # seconds per step
SCENARIO_ID_BYTES = 32  # scenario ids are stored as NUL-padded ASCII bytes

# Object types (WOMD).
TYPE_UNSET, TYPE_VEHICLE, TYPE_PEDESTRIAN, TYPE_CYCLIST, TYPE_OTHER = 0, 1, 2, 3, 4
TYPE_NAMES = ("UNSET", "VEHICLE", "PEDESTRIAN", "CYCLIST", "OTHER")  # index: the TYPE_* code
# WOMD TrafficSignalLaneState, index: the code
LIGHT_STATE_NAMES = ("UNKNOWN", "ARROW_STOP", "ARROW_CAUTION", "ARROW_GO", "STOP", "CAUTION",
                     "GO", "FLASHING_STOP", "FLASHING_CAUTION")

# Roadgraph point types (WOMD tf.Example convention).
RG_LANE_FREEWAY, RG_LANE_SURFACE_STREET, RG_LANE_BIKE = 1, 2, 3
RG_ROAD_EDGE_UNKNOWN, RG_ROAD_EDGE_BOUNDARY, RG_ROAD_EDGE_MEDIAN = 14, 15, 16
RG_STOP_SIGN, RG_CROSSWALK, RG_SPEED_BUMP = 17, 18, 19
RG_ROAD_EDGE_TYPES = (RG_ROAD_EDGE_BOUNDARY, RG_ROAD_EDGE_MEDIAN)  # used by the offroad metric
RG_NUM_TYPES = 20  # one-hot width of the roadgraph type feature


@dataclass(frozen=True)
class Capacities:
    """Fixed array sizes. Defaults are WOMD's (v1.0/1.1 tf.Example has 20,000 roadgraph points)."""

    max_objects: int = 128
    max_roadgraph_points: int = 20_000
    max_traffic_lights: int = 16
    num_steps: int = NUM_STEPS


DEFAULT_CAPS = Capacities()


@struct.dataclass
class Trajectory:
    """Per-object logged states, shape ``[..., O, T]`` each. Yaw in radians, SI units."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    yaw: np.ndarray
    vel_x: np.ndarray
    vel_y: np.ndarray
    length: np.ndarray
    width: np.ndarray
    height: np.ndarray
    valid: np.ndarray  # bool

    @property
    def speed(self):
        return (self.vel_x**2 + self.vel_y**2) ** 0.5


@struct.dataclass
class ObjectMetadata:
    """Per-object metadata, shape ``[..., O]``. ``valid`` marks a used slot (not padding)."""

    id: np.ndarray  # int32
    object_type: np.ndarray  # int32, TYPE_*
    is_sdc: np.ndarray  # bool, exactly one True per scenario
    tracks_to_predict: np.ndarray  # bool
    objects_of_interest: np.ndarray  # bool
    valid: np.ndarray  # bool


@struct.dataclass
class Roadgraph:
    """Roadgraph sample points, ``[..., R]`` (``xyz``, ``dir``: ``[..., R, 3]``); ``dir``: unit
    vector to the next point of the polyline (zero at its end), road interior on an edge's left."""

    xyz: np.ndarray
    dir: np.ndarray
    type: np.ndarray  # int32, RG_*
    id: np.ndarray  # int32 polyline id
    valid: np.ndarray  # bool


@struct.dataclass
class TrafficLights:
    """Traffic-light states, ``[..., L, T]`` each (WOMD stores ``[T, 16]``: lanes go first)."""

    state: np.ndarray  # int32, WOMD TrafficSignalLaneState enum
    valid: np.ndarray  # bool
    lane_id: np.ndarray  # int32
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray


@struct.dataclass
class Scenario:
    """One WOMD scenario (or a batch of them)."""

    trajectory: Trajectory
    metadata: ObjectMetadata
    roadgraph: Roadgraph
    traffic_lights: TrafficLights
    scenario_id: np.ndarray  # uint8 [..., SCENARIO_ID_BYTES], NUL-padded ASCII

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.metadata.is_sdc.shape[:-1])

    @property
    def num_objects(self) -> int:
        return int(self.metadata.is_sdc.shape[-1])

    @property
    def num_roadgraph_points(self) -> int:
        return int(self.roadgraph.type.shape[-1])


def encode_scenario_id(sid: str) -> np.ndarray:
    raw = sid.encode("ascii")
    if len(raw) > SCENARIO_ID_BYTES:
        raise ValueError(f"scenario id {sid!r} longer than {SCENARIO_ID_BYTES} bytes")
    return np.frombuffer(raw.ljust(SCENARIO_ID_BYTES, b"\0"), np.uint8).copy()


def read_scenario_id(sid: str | bytes, key: str) -> np.ndarray:
    """:func:`encode_scenario_id` for readers: a non-ASCII or too long id: DataError at ``key``."""
    try:
        return encode_scenario_id(sid.decode("ascii") if isinstance(sid, bytes) else sid)
    except ValueError as err:  # UnicodeError included
        raise DataError(f"bad scenario id: {err}", key=key) from None


def object_flags(ids: np.ndarray, sdc: int, predict: Iterable[int], interest) -> dict:
    """A reader's ``is_sdc``, ``tracks_to_predict`` (track indices; those outside the objects
    are ignored) and ``objects_of_interest`` (object ids) for :class:`ObjectMetadata`."""
    slots = np.arange(len(ids))
    return {"is_sdc": slots == sdc, "tracks_to_predict": np.isin(slots, list(predict)),
            "objects_of_interest": np.isin(ids, np.asarray(interest, np.int64))}


def decode_scenario_id(arr: np.ndarray) -> str:
    return bytes(np.asarray(arr, np.uint8)).rstrip(b"\0").decode("ascii")


EGO_SEPARATOR = "#"  # an ego's scenario id: <scenario id>#<object id>


def ego_id(scenario_id: str, object_id: int) -> str:
    """``<scenario id>#<object id>``; a scenario id too long to fit is replaced by its hash."""
    tail = f"{EGO_SEPARATOR}{int(object_id)}"
    if len(scenario_id) + len(tail) > SCENARIO_ID_BYTES:
        scenario_id = hashlib.sha1(scenario_id.encode()).hexdigest()[:SCENARIO_ID_BYTES - len(tail)]
    return scenario_id + tail


def split_ego_id(text: str) -> tuple[str, int | None]:
    """``(source scenario id, object id)`` of an ego id; ``(text, None)`` for a plain id."""
    head, sep, tail = text.rpartition(EGO_SEPARATOR)
    if sep and tail.lstrip("-").isdigit():
        return head, int(tail)
    return text, None


def as_ego(scenario: Scenario, slot: int) -> Scenario:
    """One unbatched scenario with object ``slot`` as the SDC and the ego's id."""
    md = scenario.metadata
    is_sdc = np.arange(scenario.num_objects) == slot
    sid = ego_id(decode_scenario_id(scenario.scenario_id), int(np.asarray(md.id)[slot]))
    return scenario.replace(metadata=md.replace(is_sdc=is_sdc), scenario_id=encode_scenario_id(sid))


def empty_scenario(caps: Capacities = DEFAULT_CAPS) -> Scenario:
    """An all-invalid scenario with the given capacities (the padding template)."""
    o, t = caps.max_objects, caps.num_steps
    r, nl = caps.max_roadgraph_points, caps.max_traffic_lights
    f = lambda *s: np.zeros(s, np.float32)
    i = lambda *s: np.zeros(s, np.int32)
    b = lambda *s: np.zeros(s, bool)
    return Scenario(
        trajectory=Trajectory(*(f(o, t) for _ in range(9)), valid=b(o, t)),  # 9 float fields
        metadata=ObjectMetadata(id=np.full(o, -1, np.int32), object_type=i(o), is_sdc=b(o),
                                tracks_to_predict=b(o), objects_of_interest=b(o), valid=b(o)),
        roadgraph=Roadgraph(xyz=f(r, 3), dir=f(r, 3), type=i(r), id=np.full(r, -1, np.int32),
                            valid=b(r)),
        traffic_lights=TrafficLights(state=i(nl, t), valid=b(nl, t), x=f(nl, t), y=f(nl, t),
                                     z=f(nl, t), lane_id=np.full((nl, t), -1, np.int32)),
        scenario_id=np.zeros(SCENARIO_ID_BYTES, np.uint8),
    )


def empty_lights(num: int) -> TrafficLights:
    """``num`` all-invalid traffic-light slots over :data:`NUM_STEPS` (a reader fills them)."""
    return empty_scenario(Capacities(0, 0, num)).traffic_lights


def stack_scenarios(scenarios: list[Scenario]) -> Scenario:
    """Stack unbatched scenarios (same capacities) into one batch along a new leading axis."""
    return jax.tree.map(lambda *xs: np.stack(xs), *scenarios)


def index_scenario(batch: Scenario, i) -> Scenario:
    return jax.tree.map(lambda x: x[i], batch)


def _fit_section(tree, template, capacity: int, valid: np.ndarray, dist: np.ndarray,
                 must_keep: np.ndarray | None = None):
    """One section (objects, roadgraph or lights) at ``capacity`` slots: every slot in place if
    they fit, else the valid ``must_keep`` slots plus the valid ones nearest by ``dist`` (in
    their original order); padded with the ``template`` leaves."""
    index = np.arange(len(valid))
    if len(index) > capacity:
        candidates = np.flatnonzero(valid)
        if len(candidates) > capacity:
            priority = dist[candidates].astype(np.float64)
            if must_keep is not None:
                priority = np.where(must_keep[candidates], -np.inf, priority)
            candidates = np.sort(candidates[np.argsort(priority, kind="stable")[:capacity]])
        index = candidates

    def one(x, pad):
        x = np.asarray(x)[index]
        missing = capacity - len(x)
        return x if missing <= 0 else np.concatenate([x, np.asarray(pad)[:missing].astype(x.dtype)])

    return jax.tree.map(one, tree, template)


def _present_distance(xy: np.ndarray, valid: np.ndarray, ref: np.ndarray, ref_t: int
                      ) -> np.ndarray:
    """Distance of each object ``xy [O, T, 2]`` to ``ref`` at its last valid step ``<= ref_t``
    (``inf`` when it has none: it appears only in the future)."""
    seen = valid[:, : ref_t + 1]
    last = seen.shape[1] - 1 - np.argmax(seen[:, ::-1], axis=1)
    pos = xy[np.arange(xy.shape[0]), last]
    return np.where(seen.any(axis=1), np.linalg.norm(pos - ref, axis=-1), np.inf)


def fit_to_capacities(scenario: Scenario, caps: Capacities = DEFAULT_CAPS) -> Scenario:
    """Pad (invalid) or reduce one unbatched scenario to exactly ``caps``.

    A section that fits keeps its slots in place (WOMD's SDC slot stays put), padding appended.
    Else invalid slots go first, then (in their original order) the SDC and what lies nearest to
    the SDC at the current step, by each object's last valid position up to then: what a policy
    may observe never depends on the logged future.
    """
    template = empty_scenario(caps)
    tr, md, rg, tl = (scenario.trajectory, scenario.metadata, scenario.roadgraph,
                      scenario.traffic_lights)
    steps = np.asarray(tr.x).shape[-1]
    if steps != caps.num_steps:
        raise ValueError(f"scenario has {steps} steps, capacities say {caps.num_steps}")
    is_sdc = np.asarray(md.is_sdc)
    sdc = int(np.argmax(is_sdc))
    xy = np.stack([np.asarray(tr.x), np.asarray(tr.y)], -1)
    valid = np.asarray(tr.valid)
    sdc_valid = valid[sdc]
    ref_t = CURRENT_INDEX if sdc_valid[CURRENT_INDEX] or not sdc_valid.any() else int(
        np.flatnonzero(sdc_valid)[0])
    ref = xy[sdc, ref_t]

    obj_dist = _present_distance(xy, valid, ref, ref_t)
    obj_valid = np.asarray(md.valid) | is_sdc
    trajectory, metadata = (_fit_section(part, pad, caps.max_objects, obj_valid, obj_dist, is_sdc)
                            for part, pad in ((tr, template.trajectory), (md, template.metadata)))
    rg_dist = np.linalg.norm(np.asarray(rg.xyz)[:, :2] - ref, axis=-1)
    roadgraph = _fit_section(rg, template.roadgraph, caps.max_roadgraph_points,
                             np.asarray(rg.valid), rg_dist)
    tl_valid = np.asarray(tl.valid)
    tl_xy = np.stack([np.asarray(tl.x), np.asarray(tl.y)], -1)
    tl_dist = np.where(tl_valid, np.linalg.norm(tl_xy - ref, axis=-1), np.inf).min(
        axis=1, initial=np.inf)
    lights = _fit_section(tl, template.traffic_lights, caps.max_traffic_lights,
                          tl_valid.any(axis=1), tl_dist)
    return Scenario(trajectory=trajectory, metadata=metadata, roadgraph=roadgraph,
                    traffic_lights=lights, scenario_id=np.asarray(scenario.scenario_id, np.uint8))


def trim_padding(scenario: Scenario) -> Scenario:
    """One unbatched scenario without its trailing padding slots, the rest in place (compact files;
    :func:`fit_to_capacities` pads it back)."""
    if scenario.batch_shape:
        raise ValueError(f"trim_padding takes one scenario, got batch {scenario.batch_shape}")

    def used(mask) -> int:
        idx = np.flatnonzero(np.asarray(mask))
        return int(idx[-1]) + 1 if len(idx) else 0

    md = scenario.metadata
    num_objects = used(np.asarray(md.valid) | np.asarray(md.is_sdc)
                       | np.asarray(scenario.trajectory.valid).any(-1))
    cut = lambda tree, n: jax.tree.map(lambda x: np.asarray(x)[:n], tree)
    return Scenario(trajectory=cut(scenario.trajectory, num_objects),
                    metadata=cut(md, num_objects),
                    roadgraph=cut(scenario.roadgraph, used(scenario.roadgraph.valid)),
                    traffic_lights=cut(scenario.traffic_lights,
                                       used(np.asarray(scenario.traffic_lights.valid).any(-1))),
                    scenario_id=np.asarray(scenario.scenario_id, np.uint8))
