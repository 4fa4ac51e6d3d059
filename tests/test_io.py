"""The atomic writers of igdrivsim.io (no JAX)."""

from __future__ import annotations

import os
import stat

import pytest

from igdrivsim.errors import DataError
from igdrivsim.io import (
    atomic_path,
    atomic_savefig,
    atomic_write,
    atomic_write_bytes,
    atomic_write_csv,
    atomic_write_json,
    atomic_write_text,
    read_json,
)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    try:
        yield 0o022
    finally:
        os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_text_write_honours_umask(tmp_path, umask_022):
    path = atomic_write_text(tmp_path / "sub" / "a.txt", "héllo\n")
    assert path.read_text(encoding="utf-8") == "héllo\n"
    assert _mode(path) == 0o666 & ~umask_022 == 0o644  # not mkstemp's 0600
    os.umask(0o027)
    assert _mode(atomic_write_bytes(tmp_path / "b.bin", b"\x00\x01")) == 0o640
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"


def test_error_keeps_old_file_and_leaves_no_temp(tmp_path):
    path = tmp_path / "out.jsonl"
    path.write_text("old\n")
    with pytest.raises(RuntimeError), atomic_path(path, "w") as f:
        f.write("half of the new")
        raise RuntimeError("crash")
    assert path.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.jsonl"]
    with pytest.raises(ValueError):
        atomic_write(tmp_path / "new.gif", lambda tmp: (tmp.write_bytes(b"x"), int("x")))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.jsonl"]


def test_atomic_write_keeps_suffix_and_json(tmp_path):
    seen = []
    atomic_write(tmp_path / "anim.gif", lambda tmp: (seen.append(tmp), tmp.write_bytes(b"GIF")))
    assert seen[0].suffix == ".gif" and seen[0].parent == tmp_path
    assert (tmp_path / "anim.gif").read_bytes() == b"GIF"
    atomic_write_json(tmp_path / "c.json", {"b": 1, "a": 2}, indent=2, sort_keys=True)
    assert (tmp_path / "c.json").read_text() == '{\n  "a": 2,\n  "b": 1\n}\n'


def test_savefig_format_from_final_suffix(tmp_path, umask_022):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1, 1))
    ax.plot([0, 1], [0, 1])
    try:
        png = atomic_savefig(fig, tmp_path / "f.png", dpi=20)
        pdf = atomic_savefig(fig, tmp_path / "f.pdf")
    finally:
        plt.close(fig)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert pdf.read_bytes()[:4] == b"%PDF"
    assert _mode(png) == 0o644
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.pdf", "f.png"]


def test_csv_round_trip(tmp_path):
    pd = pytest.importorskip("pandas")
    frame = pd.DataFrame({"setting": ["full", "noisy"], "value": [0.5, 1.25], "n": [1, 2]})
    path = atomic_write_csv(tmp_path / "t.csv", frame)
    pd.testing.assert_frame_equal(pd.read_csv(path), frame)


@pytest.mark.parametrize("content", [None, '{"a": ', '[1, 2]', b"\xff\xfe"])
def test_read_json_names_the_file_or_gives_the_default(tmp_path, content):
    """Missing, truncated, not an object or not UTF-8: one DataError naming the file, or the
    default where the caller redoes what the file held."""
    path = tmp_path / "record.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(DataError, match=f"file {path}: not readable JSON"):
        read_json(path)
    assert read_json(path, {}) == {}
    atomic_write_json(path, {"a": [1]})
    assert read_json(path) == {"a": [1]}
