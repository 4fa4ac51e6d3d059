"""The pure update: importing it never reaches the run folder (Orbax, git state), and
docs/ARCHITECTURE.md's "To add a method" example trains, run literally from the page."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types
from pathlib import Path

from conftest import write_toy_shard

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "ARCHITECTURE.md"


def test_importing_the_update_reads_no_run_folder_and_no_git():
    code = ("import sys, igdrivsim.training.update; print(sorted(m for m in sys.modules if m in "
            "('igdrivsim.training.run', 'igdrivsim.training.privileged', "
            "'igdrivsim.training.loop', 'igdrivsim.machine', 'orbax', 'git')))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]"


def _snippet(name: str) -> str:
    """The code block after ``<!-- recipe: NAME -->`` in docs/ARCHITECTURE.md."""
    after = DOC.read_text(encoding="utf-8").split(f"<!-- recipe: {name} -->", 1)[1]
    return after.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_documented_method_module_trains(tmp_path):
    from igdrivsim.training import methods
    from igdrivsim.training.config import get_profile, with_overrides
    from igdrivsim.training.loop import train
    from igdrivsim.training.update import update_spec

    name = "igdrivsim.training.methods.bc_entropy"
    sys.modules[name] = module = types.ModuleType(name)
    try:
        exec(_snippet("add-method"), module.__dict__)  # noqa: S102 - the documented module
        smoke = get_profile("smoke")
        config = with_overrides(smoke, ["training.method=bc_entropy", "training.seeds=1",
                                        "training.num_updates=2", "method.ent_bonus=0.5"])
        assert update_spec(config.validate()).params.ent_bonus == 0.5
        data = write_toy_shard(tmp_path / "data", smoke, count=4)
        result = train(config, data, tmp_path / "run", progress=False, log=lambda *_: None)
        assert result.complete and result.updates_done == 2
        lines = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text()
                 .splitlines()]
        assert [x["update"] for x in lines] == [1, 2]
        assert all(x["entropy"] > 0 and x["bc_loss"] > 0 for x in lines)
    finally:
        methods.METHODS.pop("bc_entropy", None)
        sys.modules.pop(name, None)
