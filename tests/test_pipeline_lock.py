"""A second reproduction on the same work folder is refused; a killed run leaves no stale lock."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from igdrivsim.errors import ConfigError
from igdrivsim.pipeline.profiles import PROFILES
from igdrivsim.pipeline.stages import Pipeline


def _pipeline(work) -> Pipeline:
    return Pipeline(PROFILES["smoke"], work, work / "paper")


def test_second_run_is_refused(tmp_path):
    with _pipeline(tmp_path).work_lock():
        with pytest.raises(ConfigError, match="another reproduction is running"):
            with _pipeline(tmp_path).work_lock():
                pass
    with _pipeline(tmp_path).work_lock():  # released at the end of the first
        pass


def test_killed_holder_leaves_no_stale_lock(tmp_path):
    code = ("import fcntl, sys, time; f = open(sys.argv[1], 'a+'); "
            "fcntl.flock(f, fcntl.LOCK_EX); f.write('1'); f.flush(); print('ok', flush=True); "
            "time.sleep(60)")
    holder = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "pipeline.lock")],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ok"
        with pytest.raises(ConfigError):
            with _pipeline(tmp_path).work_lock():
                pass
    finally:
        holder.kill()
        holder.wait()
    time.sleep(0.05)
    with _pipeline(tmp_path).work_lock():
        pass
