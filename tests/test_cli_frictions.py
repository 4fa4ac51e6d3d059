"""First-use frictions of the command line: empty input, generate's folder, --set vs --obs."""

from __future__ import annotations

import argparse

import pytest

from igdrivsim.cli import main
from igdrivsim.errors import ConfigError
from igdrivsim.training.commands import resolve_config, resolve_data


def test_inspect_on_an_empty_file_says_no_records(tmp_path, capsys):
    empty = tmp_path / "empty.tfrecord"
    empty.write_bytes(b"")
    assert main(["inspect", str(empty)]) == 2
    err = capsys.readouterr().err
    assert "no records" in err and "Traceback" not in err and err.count("\n") == 1


def test_train_data_takes_generates_folder(tmp_path, capsys):
    (tmp_path / "training").mkdir()
    (tmp_path / "validation").mkdir()
    assert resolve_data(str(tmp_path)) == str(tmp_path / "training")
    assert "training" in capsys.readouterr().err
    assert resolve_data(str(tmp_path / "training")) == str(tmp_path / "training")


def test_set_may_not_contradict_obs_or_method():
    args = argparse.Namespace(profile="smoke", obs="full", method="bc", seeds=None,
                              overrides=["training.method=bc_rl"])
    with pytest.raises(ConfigError, match="contradicts --method"):
        resolve_config(args)
    args.overrides = ["observation.setting=circular_r4"]
    with pytest.raises(ConfigError, match="contradicts --obs"):
        resolve_config(args)
    args.overrides = ["training.method=bc", "training.lr=3e-4"]
    config = resolve_config(args)
    assert config.training.method == "bc" and config.training.lr == 3e-4


def test_bench_train_refuses_overrides_it_would_ignore(capsys):
    """bench train fixes the method, the settings and an untrained teacher itself: a --set
    that contradicts them is refused in one line, before anything is compiled."""
    for extra in (["--method", "bc", "--set", "training.method=bc_rl"],
                  ["--set", "training.teacher=runs/bc"]):
        assert main(["bench", "train", "--profiles", "smoke", *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert "contradicts --method" in err or "training.teacher" in err
