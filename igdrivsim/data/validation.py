"""Validation scenarios, stacked, from a filter output folder or from WOMD files: what the
training curves and the evaluation are judged on."""

from __future__ import annotations

import sys
from pathlib import Path

from tqdm import tqdm

from igdrivsim.data import read_scenarios, stack_scenarios
from igdrivsim.data.manifest import count_scenarios, load_manifest_scenarios, read_manifest
from igdrivsim.errors import DataError


def load_validation(data: str, caps, max_scenarios: int = 0, progress: bool = False):
    """Stacked validation scenarios ``[N]`` from a filter output folder (``manifest.jsonl``:
    the kept scenarios) or from WOMD files (file, folder, glob, ``name@N``). ``progress``: a
    "loading" bar on stderr with the number of scenarios as its total (when it is cheap to
    know)."""
    path = Path(data)
    if (path / "manifest.jsonl").is_file():
        entries = read_manifest(path / "manifest.jsonl", kept_only=True)
        if max_scenarios:
            entries = entries[:max_scenarios]
        scenarios = load_manifest_scenarios(entries, caps, progress=progress)
    else:
        if not path.exists() and not any(ch in data for ch in "*?@"):
            raise DataError("validation data not found", file=data)
        total = count_scenarios(data, max_scenarios) if progress else None
        scenarios = []
        with tqdm(total=total, desc="loading", unit="scn", file=sys.stderr,
                  disable=not progress, dynamic_ncols=True) as bar:
            for sc in read_scenarios(data, caps):
                scenarios.append(sc)
                bar.update()
                if max_scenarios and len(scenarios) >= max_scenarios:
                    break
    if not scenarios:
        raise DataError("no validation scenarios (empty manifest or no records)", file=data)
    return stack_scenarios(scenarios)
