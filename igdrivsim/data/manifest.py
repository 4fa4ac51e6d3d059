"""Filter manifests: ``manifest.jsonl`` (one line per scenario, or per candidate ego with
``--egos all``; fields in :data:`FIELDS`, ``file`` resolved against the manifest's folder) and
``counts.json`` (docs/data.md, The paper's filter).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator

from igdrivsim.data.reader import iter_file, pool_map
from igdrivsim.data.scenario import DEFAULT_CAPS, Capacities, Scenario, decode_scenario_id
from igdrivsim.errors import DataError
from igdrivsim.io import atomic_path, atomic_write_json

MANIFEST, COUNTS = "manifest.jsonl", "counts.json"
FIELDS = ("file", "record", "scenario_id", "sdc_mean_speed", "interactive",
          "objects_of_interest", "kept")
EGO_FIELDS = ("ego", "logged_sdc")  # lines of a filter run with every vehicle as the ego


def write_json(path: str | os.PathLike, obj) -> None:
    atomic_write_json(path, obj, indent=2, sort_keys=True)


def write_manifest(path: str | os.PathLike, entries: Iterable[dict]) -> int:
    """Write manifest lines (fields in :data:`FIELDS` order) atomically; returns the count."""
    lines = [json.dumps({k: entry[k] for k in FIELDS + EGO_FIELDS if k in entry}) + "\n"
             for entry in entries]
    with atomic_path(path, "w") as f:
        f.writelines(lines)
    return len(lines)


def read_manifest(path: str | os.PathLike, kept_only: bool = True) -> list[dict]:
    """Manifest entries (only the kept ones with ``kept_only``) from a ``manifest.jsonl`` or a
    folder holding one; a bad line is a :class:`DataError` naming it."""
    path = os.fspath(path)
    if os.path.isdir(path):
        path = os.path.join(path, MANIFEST)
    if not os.path.isfile(path):
        raise DataError("no filter manifest here (run `igdrivsim filter` first)", file=path)
    base = os.path.dirname(os.path.abspath(path))
    entries = []
    with open(path) as f:
        for line_no, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                entry = json.loads(line)
            except json.JSONDecodeError as err:
                raise DataError(f"line {line_no}: bad JSON ({err.msg})", file=path) from None
            missing = [k for k in FIELDS if k not in entry] if isinstance(entry, dict) else FIELDS
            if missing:
                raise DataError(f"line {line_no}: missing field(s) {', '.join(missing)}", file=path)
            entry["file"] = os.path.normpath(os.path.join(base, entry["file"]))
            entry["record"] = int(entry["record"])
            entry["line"] = line_no
            if entry["kept"] or not kept_only:
                entries.append(entry)
    return entries


def _load_records(file: str, records: list[int], caps: Capacities | None
                  ) -> tuple[str, list[tuple[int, Scenario]]]:
    """``(file, [(record, scenario)])`` for sorted ``records`` of one file, in one forward pass."""
    if not os.path.isfile(file):
        raise DataError("manifest points at a missing file", file=file)
    wanted = set(records)
    found = {rec.record: rec.scenario
             for rec in iter_file(file, caps, start=records[0], stop=records[-1] + 1)
             if rec.record in wanted}
    if absent := [r for r in records if r not in found]:
        raise DataError("manifest points at a record the file does not have", file=file,
                        record=absent[0])
    return file, [(r, found[r]) for r in records]


def iter_manifest_scenarios(entries: Iterable[dict], caps: Capacities | None = DEFAULT_CAPS,
                            workers: int = 0, chunk: int = 32) -> Iterator[tuple[dict, Scenario]]:
    """Stream ``(entry, scenario)`` for manifest ``entries``, each file read once, front to back
    (files in order of first appearance, records ascending; ``workers``: as :func:`pool_map`);
    the manifest's scenario id must match the record's."""
    groups: dict[str, dict[int, dict]] = {}
    for e in entries:
        groups.setdefault(os.fspath(e["file"]), {})[int(e["record"])] = e
    tasks = []
    for file, by_record in groups.items():
        records = sorted(by_record)
        tasks += [(file, records[i:i + chunk], caps) for i in range(0, len(records), chunk)]
    for file, loaded in pool_map(_load_records, tasks, workers):
        for record, scenario in loaded:
            entry = groups[file][record]
            if "scenario_id" in entry and (
                    sid := decode_scenario_id(scenario.scenario_id)) != entry["scenario_id"]:
                raise DataError(f"scenario id is {sid!r}, the manifest says "
                                f"{entry['scenario_id']!r}", file=file, record=record)
            yield entry, scenario
