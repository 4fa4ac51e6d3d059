"""Protobuf message classes for the parts of tf.Example and WOMD's Scenario that we read.

The descriptors are built in Python (``descriptor_pb2`` + ``message_factory``) in a private
descriptor pool, so there is no protoc step and no clash with TensorFlow or Waymo packages. Only
the field numbers are taken from the public ``.proto`` files (tensorflow/core/example/*.proto,
waymo_open_dataset/protos/{scenario,map}.proto); fields we do not read are simply unknown fields.
"""

from __future__ import annotations

from functools import cache

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

_F = descriptor_pb2.FieldDescriptorProto
_OPT, _REP = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED
_SCALARS = {
    "double": _F.TYPE_DOUBLE, "float": _F.TYPE_FLOAT, "int64": _F.TYPE_INT64,
    "int32": _F.TYPE_INT32, "bool": _F.TYPE_BOOL, "string": _F.TYPE_STRING,
    "bytes": _F.TYPE_BYTES, "enum_as_int": _F.TYPE_INT32,
}


def _message(parent, name: str, fields, oneof: str | None = None) -> descriptor_pb2.DescriptorProto:
    """Add message ``name`` with ``fields`` = [(name, number, type, repeated)] to ``parent`` (a
    file, or a message for a nested one). ``type``: a ``_SCALARS`` name or ``.pkg.Message``; enums
    are read as int32 (same wire format), which keeps unknown enum values instead of failing.
    Repeated numbers are packed in proto3 files (tf.Example's lists), as in the ``.proto`` files."""
    top = isinstance(parent, descriptor_pb2.FileDescriptorProto)
    msg = (parent.message_type if top else parent.nested_type).add(name=name)
    if oneof:
        msg.oneof_decl.add(name=oneof)
    for fname, number, ftype, repeated in fields:
        f = msg.field.add(name=fname, number=number, label=_REP if repeated else _OPT)
        if ftype in _SCALARS:
            f.type = _SCALARS[ftype]
        else:
            f.type, f.type_name = _F.TYPE_MESSAGE, ftype
            if oneof:
                f.oneof_index = 0
    return msg


def _example_file() -> descriptor_pb2.FileDescriptorProto:
    file = descriptor_pb2.FileDescriptorProto(name="igdrivsim_example.proto",
                                              package="igdrivsim.tfex", syntax="proto3")
    p = ".igdrivsim.tfex."
    _message(file, "BytesList", [("value", 1, "bytes", True)])
    _message(file, "FloatList", [("value", 1, "float", True)])
    _message(file, "Int64List", [("value", 1, "int64", True)])
    _message(file, "Feature", [("bytes_list", 1, p + "BytesList", False),
                               ("float_list", 2, p + "FloatList", False),
                               ("int64_list", 3, p + "Int64List", False)], oneof="kind")
    feats = _message(file, "Features", [("feature", 1, p + "Features.FeatureEntry", True)])
    entry = _message(feats, "FeatureEntry", [("key", 1, "string", False),
                                             ("value", 2, p + "Feature", False)])
    entry.options.map_entry = True
    _message(file, "Example", [("features", 1, p + "Features", False)])
    return file


def _scenario_file() -> descriptor_pb2.FileDescriptorProto:
    file = descriptor_pb2.FileDescriptorProto(name="igdrivsim_scenario.proto",
                                              package="igdrivsim.womd", syntax="proto2")
    p = ".igdrivsim.womd."
    # map.proto
    _message(file, "MapPoint", [("x", 1, "double", False), ("y", 2, "double", False),
                                ("z", 3, "double", False)])
    _message(file, "TrafficSignalLaneState", [("lane", 1, "int64", False),
                                              ("state", 2, "enum_as_int", False),
                                              ("stop_point", 3, p + "MapPoint", False)])
    _message(file, "DynamicMapState", [("lane_states", 1, p + "TrafficSignalLaneState", True)])
    _message(file, "LaneCenter", [("speed_limit_mph", 1, "double", False),
                                  ("type", 2, "enum_as_int", False),
                                  ("polyline", 8, p + "MapPoint", True)])
    _message(file, "RoadLine", [("type", 1, "enum_as_int", False),
                                ("polyline", 2, p + "MapPoint", True)])
    _message(file, "RoadEdge", [("type", 1, "enum_as_int", False),
                                ("polyline", 2, p + "MapPoint", True)])
    _message(file, "StopSign", [("lane", 1, "int64", True), ("position", 2, p + "MapPoint", False)])
    for name in ("Crosswalk", "SpeedBump", "Driveway"):
        _message(file, name, [("polygon", 1, p + "MapPoint", True)])
    _message(file, "MapFeature", [
        ("lane", 3, p + "LaneCenter", False), ("road_line", 4, p + "RoadLine", False),
        ("road_edge", 5, p + "RoadEdge", False), ("stop_sign", 7, p + "StopSign", False),
        ("crosswalk", 8, p + "Crosswalk", False), ("speed_bump", 9, p + "SpeedBump", False),
        ("driveway", 10, p + "Driveway", False), ("id", 1, "int64", False)], oneof="feature_data")
    # scenario.proto
    _message(file, "ObjectState", [
        ("center_x", 2, "double", False), ("center_y", 3, "double", False),
        ("center_z", 4, "double", False), ("length", 5, "float", False),
        ("width", 6, "float", False), ("height", 7, "float", False),
        ("heading", 8, "float", False), ("velocity_x", 9, "float", False),
        ("velocity_y", 10, "float", False), ("valid", 11, "bool", False)])
    _message(file, "Track", [("id", 1, "int32", False), ("object_type", 2, "enum_as_int", False),
                             ("states", 3, p + "ObjectState", True)])
    _message(file, "RequiredPrediction", [("track_index", 1, "int32", False),
                                          ("difficulty", 2, "enum_as_int", False)])
    _message(file, "Scenario", [
        ("timestamps_seconds", 1, "double", True), ("tracks", 2, p + "Track", True),
        ("objects_of_interest", 4, "int32", True), ("scenario_id", 5, "string", False),
        ("sdc_track_index", 6, "int32", False),
        ("dynamic_map_states", 7, p + "DynamicMapState", True),
        ("map_features", 8, p + "MapFeature", True), ("current_time_index", 10, "int32", False),
        ("tracks_to_predict", 11, p + "RequiredPrediction", True)])
    return file


@cache
def _message_class(name: str) -> type:
    pool = descriptor_pool.DescriptorPool()
    file = _example_file() if name == "Example" else _scenario_file()
    pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{file.package}.{name}"))


def example_class() -> type:
    """The tf.Example message class (``features.feature[key].{float,int64,bytes}_list.value``)."""
    return _message_class("Example")


def scenario_class() -> type:
    """WOMD's Scenario message class (tracks, map features, dynamic map states)."""
    return _message_class("Scenario")
