"""One way in for data: :func:`open_scenarios` reads whatever a data path names (a filter output
folder, or files of any registered format; docs/data.md, Inputs); the other functions answer
questions about a path without reading it whole, or stack its scenarios (validation sets).
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Iterator
from itertools import chain, islice, repeat

import numpy as np
from tqdm import tqdm

from igdrivsim.data.egos import PAPER_FILTER, check_egos, ego_of, ego_slot, expand_egos
from igdrivsim.data.filter import FilterConfig
from igdrivsim.data.formats import format_of
from igdrivsim.data.manifest import COUNTS, MANIFEST, iter_manifest_scenarios, read_manifest
from igdrivsim.data.reader import (
    PathSpec,
    ReadStats,
    ScenarioRecord,
    as_paths,
    expand_paths,
    iter_file,
    iter_scenarios,
)
from igdrivsim.data.scenario import (
    DEFAULT_CAPS,
    Capacities,
    Scenario,
    decode_scenario_id,
    fit_to_capacities,
    split_ego_id,
    stack_scenarios,
)
from igdrivsim.errors import DataError


def check_data(data, what: str) -> None:
    """One-line :class:`DataError` "``what`` data not found" when a location of ``data`` (a
    path or a list of them) names nothing; globs and ``name@N`` are left to the reader."""
    for where in as_paths(data):
        if not os.path.exists(where) and not any(ch in where for ch in "*?@"):
            raise DataError(f"{what} data not found", file=where)


def manifest_of(path) -> str | None:
    """``PATH/manifest.jsonl`` when ``path`` is a filter output folder, else None; a filter
    folder without one (an unfinished run) is a one-line :class:`DataError`."""
    if not isinstance(path, str | os.PathLike) or not os.path.isdir(path):
        return None
    manifest = os.path.join(os.fspath(path), MANIFEST)
    if os.path.isfile(manifest):
        return manifest
    if os.path.isfile(os.path.join(os.fspath(path), COUNTS)):
        raise DataError(f"a filter output folder without {MANIFEST} (an unfinished "
                        "`igdrivsim filter` run?)", file=os.fspath(path))
    return None


def _fit(rec: ScenarioRecord, caps: Capacities | None) -> ScenarioRecord:
    return rec if caps is None else rec._replace(scenario=fit_to_capacities(rec.scenario, caps))


def _from_manifest(manifest: str, caps, egos: str, config: FilterConfig, limit: int,
                   workers: int) -> Iterator[ScenarioRecord]:
    entries = read_manifest(manifest, kept_only=True)
    per_ego = any("ego" in e for e in entries)  # written by `filter --egos all`
    if egos == "sdc" and not per_ego and limit:
        entries = entries[:limit]
    wanted: dict[tuple[str, int], list[dict]] = {}
    for e in entries:
        wanted.setdefault((e["file"], e["record"]), []).append(e)
    first = [group[0] for group in wanted.values()]
    decode_caps = None if egos == "all" or per_ego else caps
    order, done = list(wanted)[::-1], {}  # the manifest's order, the next one last
    # each file is read once, front to back; the records come out in the manifest's order
    for entry, scenario in iter_manifest_scenarios(first, decode_caps, workers):
        done[(entry["file"], entry["record"])] = scenario
        while order and order[-1] in done:
            ref = order.pop()
            yield from _manifest_records(ref, done.pop(ref), wanted[ref], caps, egos, per_ego,
                                         config)


def _manifest_records(ref: tuple[str, int], scenario, lines: list[dict], caps, egos: str,
                      per_ego: bool, config: FilterConfig) -> Iterator[ScenarioRecord]:
    file, record = ref
    rec = ScenarioRecord(file, record, format_of(file).name, scenario)
    if per_ego:
        for e in lines:
            if (slot := ego_slot(scenario, e["ego"])) is None:
                raise DataError(f"manifest line {e['line']}: no object {e['ego']}",
                                file=file, record=record)
            yield from _egos_of(rec, caps, config, only=slot)
    elif egos == "all":
        yield from _egos_of(rec, caps, config)
    else:
        yield from repeat(rec, len(lines))  # a line repeated reads twice, as it is written


def _egos_of(rec: ScenarioRecord, caps, config: FilterConfig, only: int | None = None
             ) -> Iterator[ScenarioRecord]:
    """The record once per eligible ego (``only``: that slot, taken as it is)."""
    egos = [ego_of(rec.scenario, only)] if only is not None else expand_egos(rec.scenario, config)
    for scenario, info in egos:
        yield _fit(rec._replace(scenario=scenario, ego=info), caps)


def open_scenarios(path: PathSpec, caps: Capacities | None = DEFAULT_CAPS, *,
                   egos: str = "sdc", filter_config: FilterConfig = PAPER_FILTER,
                   limit: int = 0, skip_bad: bool = False, stats: ReadStats | None = None,
                   workers: int = 0) -> Iterator[ScenarioRecord]:
    """Stream the scenarios ``path`` names (docs/data.md, Inputs) as :class:`ScenarioRecord`,
    fitted to ``caps`` (None: native sizes), at most ``limit`` (0: all); ``egos="all"``: one per
    vehicle eligible under ``filter_config``. ``skip_bad``, ``stats`` and ``workers`` are the
    reader's (:func:`~igdrivsim.data.reader.iter_scenarios`)."""
    check_egos(egos)

    def records(item: str) -> Iterator[ScenarioRecord]:
        if (manifest := manifest_of(item)) is not None:
            yield from _from_manifest(manifest, caps, egos, filter_config, limit, workers)
        elif egos == "sdc":
            yield from iter_scenarios(item, caps, skip_bad, stats, workers)
        else:
            for rec in iter_scenarios(item, None, skip_bad, stats, workers):
                yield from _egos_of(rec, caps, filter_config)

    yield from islice(chain.from_iterable(map(records, as_paths(path))), limit or None)


def count_scenarios(data, max_scenarios: int = 0, egos: str = "sdc") -> int | None:
    """How many scenarios :func:`open_scenarios` yields for ``data`` (at most ``max_scenarios``; 0:
    no cap), for a progress bar's total; None where that is not cheap (every vehicle as the ego,
    ScenarioNet) or the path does not read (the read itself reports it)."""
    total = 0
    try:
        for item in as_paths(data):
            if (manifest := manifest_of(item)) is not None:
                entries = read_manifest(manifest)
                if egos == "all" and not any("ego" in e for e in entries):
                    return None
                total += len(entries)
            elif egos == "all":
                return None
            else:
                for path in expand_paths(item):
                    if max_scenarios and total >= max_scenarios:
                        break
                    fmt = format_of(path)
                    if not fmt.cheap_count:
                        return None
                    total += fmt.count(path)
            if max_scenarios and total >= max_scenarios:
                break
    except (DataError, OSError):
        return None
    return min(total, max_scenarios) if max_scenarios else total


def data_identity(data) -> str:
    """Changes when the data does: the manifest's bytes, the files' names, sizes and mtimes."""
    h = hashlib.sha256()
    manifest = manifest_of(data)
    if manifest is None:
        files = expand_paths(data)
    else:  # the manifest's bytes and the files it points at (kept or not)
        with open(manifest, "rb") as f:
            h.update(f.read())
        files = sorted({e["file"] for e in read_manifest(manifest, kept_only=False)})
    for name in files:
        if not os.path.isfile(name):
            raise DataError("the filter manifest points at a missing file", file=name)
        st = os.stat(name)
        h.update(f"{os.path.abspath(name)}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()


def scenario_refs(data, limit: int = 0, egos: str = "sdc",
                  filter_config: FilterConfig = PAPER_FILTER) -> tuple[list[str], np.ndarray]:
    """A compact index of the scenarios of ``data``: ``(files, refs [N, 3])``, each row
    ``(file id, record, ego object id or -1 for the logged SDC)``; read one with
    :func:`load_ref`. Only ``egos="all"`` decodes (eligibility needs the trajectories)."""
    files: dict[str, int] = {}
    refs = [(files.setdefault(file, len(files)), record, ego)
            for file, record, ego in islice(_refs(data, limit, egos, filter_config), limit or None)]
    if not refs:
        raise DataError("no scenarios found", file=str(data))
    return list(files), np.asarray(refs, np.int64).reshape(-1, 3)


def _refs(data, limit: int, egos: str, filter_config: FilterConfig
          ) -> Iterator[tuple[str, int, int]]:
    for item in as_paths(data):
        manifest = manifest_of(item)
        if egos == "all" or (manifest is not None and any(
                "ego" in e for e in read_manifest(manifest))):
            for rec in open_scenarios(item, None, egos=egos, filter_config=filter_config,
                                      limit=limit):
                yield rec.file, rec.record, -1 if rec.ego is None else rec.ego["object_id"]
        elif manifest is not None:
            yield from ((e["file"], e["record"], -1) for e in read_manifest(manifest))
        else:
            yield from ((name, r, -1) for name in expand_paths(item)
                        for r in range(format_of(name).count(name)))


def load_ref(file: str, record: int, ego: int, caps: Capacities | None) -> Scenario:
    """The scenario of one :func:`scenario_refs` row, fitted to ``caps``."""
    rec = next(iter_file(file, None, start=record, stop=record + 1), None)
    if rec is None or rec.record != record:
        raise DataError("no such record (the file changed?)", file=file, record=record)
    if ego < 0:
        return _fit(rec, caps).scenario
    if (slot := ego_slot(rec.scenario, ego)) is None:
        raise DataError(f"no object {ego} (the file changed?)", file=file, record=record)
    return next(_egos_of(rec, caps, PAPER_FILTER, only=slot)).scenario


def origin_of(rec: ScenarioRecord) -> dict:
    """Where one read scenario comes from: ``{"scenario_id", "source", "logged_sdc"}``.
    ``source`` is the source log: for a window cut from a long log (ScenarioNet), the reader's
    source id; for an ego of ``egos="all"``, its scenario's id; else the scenario's own id.
    ``logged_sdc``: whether the ego is the log's SDC (always, with ``egos="sdc"``)."""
    sid = decode_scenario_id(rec.scenario.scenario_id)
    if rec.source and rec.source.get("source_id"):
        source = str(rec.source["source_id"])
    else:
        source = split_ego_id(sid)[0] if rec.ego is not None else sid
    return {"scenario_id": sid, "source": source,
            "logged_sdc": True if rec.ego is None else bool(rec.ego["logged_sdc"])}


def load_scenarios(data, caps, max_scenarios: int = 0, progress: bool = False,
                   egos: str = "sdc") -> tuple:
    """``(stacked scenarios [N], origins)`` of ``data`` (a location or a list of them), one
    :func:`origin_of` dict per scenario; see :func:`load_validation`."""
    check_data(data, "validation")
    total = count_scenarios(data, max_scenarios, egos) if progress else None
    scenarios, origins = [], []
    with tqdm(total=total, desc="loading", unit="scn", file=sys.stderr,
              disable=not progress, dynamic_ncols=True) as bar:
        for rec in open_scenarios(data, caps, egos=egos, limit=max_scenarios):
            scenarios.append(rec.scenario)
            origins.append(origin_of(rec))
            bar.update()
    if not scenarios:
        raise DataError("no validation scenarios (empty manifest or no records)", file=str(data))
    return stack_scenarios(scenarios), origins


def load_validation(data, caps, max_scenarios: int = 0, progress: bool = False, egos: str = "sdc"):
    """Stacked validation scenarios ``[N]`` of ``data`` (:func:`load_scenarios`); ``progress``: a
    "loading" bar on stderr, with a total where that is cheap to know."""
    return load_scenarios(data, caps, max_scenarios, progress, egos)[0]
