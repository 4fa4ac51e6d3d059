"""Where, when and with which code something ran: the ``machine`` record every ``igdrivsim
bench --out`` file carries, so a speed cited in the docs names its machine, date and load; and
the code's state (commit, dirty tree, diff hash) that training runs, evaluations and the
pipeline's stage stamps record, so a number names the code that produced it."""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import platform
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path


def machine_record() -> dict:
    """CPU count, load, OS, Python, JAX, its devices and matmul precision, date, command line."""
    import jax  # lazy: JAX only when a record is taken

    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not available on this platform
        load = None
    return {"date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "cpus": os.cpu_count(), "load_average_1_5_15_min": load,
            "platform": platform.platform(), "processor": platform.processor() or None,
            "python": platform.python_version(), "jax": jax.__version__,
            "backend": jax.default_backend(),
            "devices": sorted({d.device_kind for d in jax.devices()}),
            # JAX_DEFAULT_MATMUL_PRECISION changes what a float32 product costs on a GPU
            "matmul_precision": jax.config.jax_default_matmul_precision,
            "command": " ".join(["igdrivsim", *sys.argv[1:]]) if sys.argv else None}


def process_cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and of its finished (joined) worker
    processes: a cost that a machine shared with other work does not distort."""
    import resource  # Unix only

    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


PACKAGE_REPO = Path(__file__).resolve().parents[1]  # the checkout holding this package
CODE_KEYS = ("commit", "dirty", "diff_hash")
UNKNOWN_CODE = dict.fromkeys(CODE_KEYS)  # not a git checkout (an installed package), or no git
# what the pipeline itself writes into the checkout: not code, so it does not make it dirty
OWN_OUTPUTS = ("paper", "docs/results.md", "README.md")


def code_state(repo: str | Path = PACKAGE_REPO) -> dict:
    """``{"commit", "dirty", "diff_hash"}`` of the git checkout ``repo`` (``diff_hash``: 12 hex
    digits of the sha256 of ``git diff HEAD`` but :data:`OWN_OUTPUTS`); all None outside one."""
    repo = Path(repo).resolve()

    def git(*args: str) -> bytes:
        return subprocess.run(["git", *args], cwd=repo, capture_output=True, check=True,
                              timeout=60).stdout

    try:
        if Path(git("rev-parse", "--show-toplevel").decode().strip()).resolve() != repo:
            return dict(UNKNOWN_CODE)  # e.g. an installed package inside another checkout
        commit = git("rev-parse", "--short", "HEAD").decode().strip()
        diff = git("diff", "--no-ext-diff", "--no-color", "--binary", "HEAD", "--", ".",
                   *(f":(exclude){path}" for path in OWN_OUTPUTS))
    except (OSError, subprocess.SubprocessError, UnicodeDecodeError):
        return dict(UNKNOWN_CODE)
    return {"commit": commit, "dirty": bool(diff),
            "diff_hash": hashlib.sha256(diff).hexdigest()[:12] if diff else None}


def code_label(state: Mapping) -> str:
    """``abc1234``, ``abc1234-dirty (diff 0123456789ab)`` or ``unknown``."""
    commit = state.get("commit") or "unknown"
    return f"{commit}-dirty (diff {state.get('diff_hash')})" if state.get("dirty") else commit
