"""Bad input on the command line: one line naming the option, value or file, exit 2, found
before any work is done (no traceback, nothing half-written)."""

from __future__ import annotations

import json
import signal
import warnings

import pytest

from igdrivsim.cli import main
from igdrivsim.data.source import data_identity
from igdrivsim.errors import ConfigError, DataError
from igdrivsim.pipeline.cli import build_parser, pipeline_from_args
from igdrivsim.pipeline.cli import main as reproduce
from igdrivsim.training.config import get_profile, with_overrides


def one_line_error(capsys, *needles: str) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def a_file(tmp_path):
    path = tmp_path / "a_file"
    path.write_text("x")
    return path


@pytest.mark.parametrize("argv", [
    ["generate", "--train", "1", "--val", "0"], ["filter", "IN"], ["replay", "IN"],
    ["render", "--data", "IN"], ["evaluate", "--references", "--data", "IN"],
    ["report", "--evals", "IN"]])
def test_an_output_folder_that_is_a_file_is_refused_up_front(argv, a_file, capsys):
    assert main([*argv, "--out", str(a_file)]) == 2
    one_line_error(capsys, "--out", str(a_file), "not a folder")


def test_a_file_system_refusal_is_one_line(a_file, capsys):
    """An OSError the commands do not foresee (here: a folder under a file) is one line."""
    assert main(["generate", "--out", str(a_file / "sub"), "--train", "1", "--val", "0"]) == 2
    one_line_error(capsys, str(a_file))


def test_train_refuses_an_output_file(a_file, capsys):
    assert main(["train", "--profile", "smoke", "--data", str(a_file), "--out",
                 str(a_file)]) == 2
    one_line_error(capsys, "--out", "not a folder")


@pytest.mark.parametrize("override, field", [
    ("policy.gru_hidden=0", "policy.gru_hidden"), ("data.max_objects=0", "data.max_objects"),
    ("training.log_every=0", "training.log_every"), ("training.lr=nan", "training.lr"),
    ("training.lr=-1", "training.lr"), ("loss.gamma=1.5", "loss.gamma"),
    ("policy.object_hidden=[64,0]", "policy.object_hidden"),
    ("policy.num_bins=1", "policy.num_bins"),
    ("training.ppo_minibatches=0", "training.ppo_minibatches")])
def test_config_values_out_of_range_are_refused(override, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        with_overrides(get_profile("smoke"), [override]).validate()


def test_a_loss_term_under_training_names_its_section():
    with pytest.raises(ConfigError, match=r"--set loss\.w_rl=0\.1"):
        with_overrides(get_profile("smoke"), ["training.w_rl=0.1"])


def test_every_profile_is_within_range():
    for name in ("smoke", "laptop", "gpu", "paper"):
        get_profile(name).validate()


@pytest.mark.parametrize("argv, needle", [
    (["train", "--profile", "smoke", "--data", "x", "--out", "y", "--stop-after", "-1"],
     "--stop-after must be >= 0, got -1"),
    (["bench", "train", "--profiles", "smoke", "--updates", "0"], "--updates must be >= 1"),
    (["bench", "train", "--profiles", ","], "--profiles names no profile"),
    (["inspect", "--workers", "0", "x"], "--workers must be >= 1, got 0"),
    (["generate", "--out", "OUT", "--workers", "0"], "--workers must be >= 1, got 0"),
    (["generate", "--out", "OUT", "--plot", "-1"], "--plot must be >= 0, got -1"),
    (["bench", "sim", "--repeats", "0"], "--repeats must be >= 1, got 0"),
])
def test_numeric_options_name_the_option_and_value(argv, needle, tmp_path, capsys,
                                                   monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    one_line_error(capsys, needle)
    assert not (tmp_path / "OUT").exists()


def test_skipped_bad_record_is_one_warning_line(tmp_path, capsys):
    """pytest records warnings itself, so the line the command prints is checked through the
    formatter the command installs."""
    bad = tmp_path / "bad.tfrecord"
    bad.write_text("not a tfrecord")
    with pytest.warns(UserWarning, match="skipping bad record"):
        assert main(["inspect", "--skip-bad", str(bad)]) == 2
    capsys.readouterr()
    line = warnings.formatwarning("skipping bad record: x", UserWarning, "reader.py", 61)
    assert line == "igdrivsim inspect: warning: skipping bad record: x\n"


def test_training_data_identity_reads_the_manifest_like_the_loader(tmp_path):
    data = tmp_path / "data.tfrecord"
    data.write_bytes(b"")
    entry = {"file": "data.tfrecord", "record": 0, "scenario_id": "s", "sdc_mean_speed": 5.0,
             "interactive": True, "objects_of_interest": 2, "kept": True}
    folder = tmp_path / "filtered"
    folder.mkdir()
    manifest = folder / "manifest.jsonl"
    manifest.write_text(json.dumps({**entry, "file": "../data.tfrecord"}) + "\n")
    assert data_identity(folder)  # a relative path resolves against the manifest's folder
    manifest.write_text(json.dumps({**entry, "file": "../gone.tfrecord"}) + "\n")
    with pytest.raises(DataError, match="missing file"):
        data_identity(folder)
    manifest.write_text("{not json\n")
    with pytest.raises(DataError, match="line 1: bad JSON"):
        data_identity(folder)


@pytest.mark.parametrize("extra, needle", [
    (["--obs", "full,full"], "distinct settings"),
    (["--set", "observation.setting=full"], "the pipeline sets observation.setting"),
    (["--data", "NOPE/tr", "NOPE/va"], "NOPE/tr"),
])
def test_reproduce_checks_its_arguments_before_any_stage(extra, needle, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = build_parser().parse_args(["--profile", "smoke", "--out", "work", *extra])
    with pytest.raises((ConfigError, DataError), match=needle):
        pipeline_from_args(args)
    assert not (tmp_path / "work").exists()


def test_reproduce_gives_sigterm_back_to_its_caller(tmp_path, monkeypatch, capsys):
    """main() turns SIGTERM into an interrupt while it runs, then restores the caller's handler
    (a process that calls it, a test worker, keeps its own)."""
    def mine(signum, frame):
        pass

    monkeypatch.chdir(tmp_path)
    before = signal.signal(signal.SIGTERM, mine)
    try:
        assert reproduce(["--profile", "smoke", "--out", "work", "--obs", "full,full"]) == 2
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, before)
    assert "distinct settings" in capsys.readouterr().err


def test_every_command_line_reports_through_run_command(capsys):
    """One helper turns a command's error into its line and exit status
    (igdrivsim.errors.run_command); no other module catches the reported errors itself."""
    from pathlib import Path

    from igdrivsim.errors import run_command

    def fails():
        raise ConfigError("--x must be >= 1, got 0")

    assert run_command("tool", fails) == 2
    assert capsys.readouterr().err == "tool: error: --x must be >= 1, got 0\n"
    assert run_command("tool", lambda: None) == 0 and run_command("tool", lambda n: n, 1) == 1
    root = Path(__file__).resolve().parents[1]
    catching = [p.relative_to(root).as_posix() for pkg in ("igdrivsim", "maze")
                for p in (root / pkg).rglob("*.py") if "except REPORTED" in p.read_text()]
    assert catching == ["igdrivsim/errors.py"]
