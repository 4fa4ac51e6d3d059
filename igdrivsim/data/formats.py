"""The registry of data formats: how a file is recognised (``detect``), decoded (``decode``: its
scenarios at native sizes, a bad record as a :class:`DataError` in place of its scenario) and
counted (``count``). Adding a format is one module plus one entry of :data:`FORMATS`
(docs/data.md, Inputs; tests/test_data_formats.py adds one).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from google.protobuf.message import DecodeError

from igdrivsim.data import gpudrive, scenarionet, tfrecord
from igdrivsim.data.protos import example_class, scenario_class
from igdrivsim.data.scenario import Scenario
from igdrivsim.data.tfexample import decode_tfexample, is_tfexample
from igdrivsim.data.womd_proto import decode_scenario_proto, is_scenario_proto
from igdrivsim.errors import DataError

FORMAT_TFEXAMPLE, FORMAT_SCENARIO = "tf_example", "scenario_proto"
Decoded = tuple[int, str | None, Scenario | DataError, dict | None]


@dataclass(frozen=True)
class Format:
    """One data format: recognise a file, decode its scenarios, count them."""

    name: str
    detect: Callable[[str], bool]
    decode: Callable[[str, int, int | None], Iterator[Decoded]]
    count: Callable[[str], int]
    cheap_count: bool = True  # False: counting decodes the whole file
    lists: Callable[[str], bool] = lambda path: True  # whether a folder listing takes the file
    folder: Callable[[str], list[str] | None] = lambda folder: None  # a dataset folder's files
    dataset: Callable[[str], str | None] = lambda path: "WOMD"  # where a file's scenarios come from


def decode_record(data: bytes) -> tuple[str, Scenario]:
    """``(format, scenario)`` of one TFRecord record: a WOMD tf.Example or Scenario protobuf."""
    kinds = (FORMAT_TFEXAMPLE, FORMAT_SCENARIO)
    for kind in kinds if data[:1] == b"\x0a" else kinds[::-1]:
        try:
            if kind == FORMAT_TFEXAMPLE:
                if is_tfexample(example_class().FromString(data)):
                    return kind, decode_tfexample(data)
            elif is_scenario_proto(message := scenario_class().FromString(data)):
                return kind, decode_scenario_proto(message)
        except DecodeError:
            continue
    raise DataError("unknown record format: neither a WOMD tf.Example nor a Scenario protobuf")


def _decode_tfrecord(path: str, start: int, stop: int | None) -> Iterator[Decoded]:
    """Records of a TFRecord file; a bad record comes as its :class:`DataError`."""
    for index, data, error in tfrecord.iter_frames(path, start=start):
        if stop is not None and index >= stop:
            return
        try:
            if error is not None:
                raise error
            fmt, scenario = decode_record(data)
        except DataError as err:
            fmt, scenario = None, err
        yield index, fmt, scenario, None


def _decode_scenarionet(path: str, start: int, stop: int | None) -> Iterator[Decoded]:
    """The 91-step windows of a ScenarioNet log (a bad file is one bad record)."""
    for index, (scenario, source) in enumerate(scenarionet.read_file(path)):
        if index >= start and (stop is None or index < stop):
            yield index, scenarionet.FORMAT_SCENARIONET, scenario, source


def _decode_gpudrive(path: str, start: int, stop: int | None) -> Iterator[Decoded]:
    """The one scenario of a GPUDrive JSON file."""
    if start <= 0 and (stop is None or stop > 0):
        yield 0, gpudrive.FORMAT_GPUDRIVE, gpudrive.read_file(path), None


FORMATS: dict[str, Format] = {
    # the dataset's index pickles are detected (and decode to a one-line error), never listed
    "scenarionet": Format("scenarionet", lambda path: path.endswith(scenarionet.PICKLE_SUFFIXES),
                          _decode_scenarionet, lambda path: len(scenarionet.read_file(path)),
                          cheap_count=False, lists=scenarionet.is_scenarionet_file,
                          folder=scenarionet.dataset_files, dataset=scenarionet.source_dataset),
    "gpudrive": Format("gpudrive", gpudrive.is_gpudrive_file, _decode_gpudrive, lambda path: 1),
    # WOMD tf.Examples or Scenario protos (told apart per record); the fallback for every file no
    # other format detects; a folder listing takes names containing "tfrecord"
    "tfrecord": Format("tfrecord", lambda path: True, _decode_tfrecord, tfrecord.count_records,
                       lists=lambda path: "tfrecord" in os.path.basename(path)),
}
FALLBACK = "tfrecord"


def format_of(path: str) -> Format:
    return next((f for name, f in FORMATS.items() if name != FALLBACK and f.detect(path)),
                FORMATS[FALLBACK])


def folder_files(folder: str) -> list[str]:
    """The files a folder reads: a format's dataset folder's, else those of the first format
    that lists any (TFRecords first, then registry order), else every file no other format
    detects."""
    for fmt in FORMATS.values():
        if (listed := fmt.folder(folder)) is not None:
            return listed
    by_format: dict[str, list[str]] = {}
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if not name.startswith(".") and os.path.isfile(path):
            fmt = format_of(path)
            if fmt.lists(path):
                by_format.setdefault(fmt.name, []).append(path)
            elif fmt.name == FALLBACK:
                by_format.setdefault("", []).append(path)
    order = [FALLBACK, *(n for n in FORMATS if n != FALLBACK), ""]
    return next((by_format[n] for n in order if n in by_format), [])
