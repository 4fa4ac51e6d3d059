"""``igdrivsim samples``: real WOMD scenarios a user can fetch without a WOMD licence of their own.

MetaDrive's wheel (:data:`PACKAGE`, 49 MB) ships three real WOMD scenarios as MetaDrive 0.2
pickles (read by :mod:`igdrivsim.data.scenarionet`). This command gets the wheel with ``pip
download`` (no other network code), extracts them into ``OUT/womd/`` with every sha256 checked,
and later verifies and reuses them offline (docs/scenarionet.md).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from igdrivsim.errors import DataError
from igdrivsim.io import atomic_write_bytes, atomic_write_json, require_folder

PACKAGE = "metadrive-simulator==0.2.6.0"
WHEEL = "metadrive_simulator-0.2.6.0-py3-none-any.whl"
WHEEL_SHA256 = "4d5c2c4d5acc52a4596b76fcdd3f4cdb35ac812270cc4298779763c9730f2109"
SUBDIR = "womd"
# wheel member -> (file under OUT/womd, sha256, WOMD scenario id)
FILES: dict[str, tuple[str, str, str]] = {
    f"metadrive/assets/waymo/{i}.pkl": (f"{i}.pkl", digest, sid) for i, (digest, sid) in enumerate((
        ("d11856cdc81285cd8b23566d4363f5f4912bcc7da4760ba0af4613e827e36bf3", "2831b6fde0420b0d"),
        ("e0b79e64d0b413317d9d3d17c92de3b1dcef6d15510170a264ba599308d90089", "1446dc44bd6fd420"),
        ("505939e3e3bac02b96cca3bde2cd44ba8d567577ea0c8867558187886893d2cf", "8d3d061e518531d0")))}
TERMS = ("real scenarios of the Waymo Open Motion Dataset, as redistributed in MetaDrive's "
         f"wheel ({PACKAGE}); they come under the Waymo Open Dataset License Agreement for "
         "Non-Commercial Use (https://waymo.com/open/terms/): non-commercial use only, not "
         "part of this repository")
RECORD = "samples.json"


def default_dir() -> Path:
    """``$XDG_CACHE_HOME/igdrivsim/samples`` (``~/.cache/igdrivsim/samples`` by default)."""
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(cache) / "igdrivsim" / "samples"


def scenario_dir(out: str | os.PathLike) -> Path:
    return Path(out) / SUBDIR


def sha256(path: str | os.PathLike) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def verified(out: str | os.PathLike) -> list[Path] | None:
    """The scenario files under ``out`` when all are there with their hashes, else None."""
    paths = [scenario_dir(out) / name for name, _, _ in FILES.values()]
    ok = all(p.is_file() and sha256(p) == h for p, (_, h, _) in zip(paths, FILES.values(),
                                                                     strict=True))
    return paths if ok else None


def find_samples(out: str | os.PathLike | None = None) -> Path | None:
    """The verified scenario folder under ``out`` (default: :func:`default_dir`), or None."""
    out = default_dir() if out is None else Path(out)
    return scenario_dir(out) if verified(out) else None


def download_wheel(dest: Path) -> Path:
    """``pip download PACKAGE --no-deps`` into ``dest``; the wheel's path."""
    cmd = [sys.executable, "-m", "pip", "download", PACKAGE, "--no-deps", "--only-binary=:all:",
           "--disable-pip-version-check", "-d", str(dest)]
    proc = subprocess.run(cmd, stdout=sys.stderr, stderr=subprocess.PIPE, text=True)
    wheels = sorted(dest.glob("*.whl"))
    if proc.returncode != 0 or not wheels:
        last = (proc.stderr or "").strip().splitlines()[-1:] or ["no wheel written"]
        raise DataError(f"pip download {PACKAGE} failed (exit {proc.returncode}): {last[0]}; "
                        f"without network, pass a downloaded {WHEEL} with --wheel")
    return wheels[0]


def extract(wheel: Path, out: Path) -> list[Path]:
    """Check the wheel's hash, write the listed members under ``out/womd`` (atomically), each
    checked against its hash before it is written."""
    if (got := sha256(wheel)) != WHEEL_SHA256:
        raise DataError(f"sha256 {got}, expected {WHEEL_SHA256}", file=str(wheel))
    written = []
    try:
        with zipfile.ZipFile(wheel) as zf:
            for member, (name, digest, _) in FILES.items():
                try:
                    data = zf.read(member)
                except KeyError:
                    raise DataError("member missing from the wheel", file=str(wheel),
                                    key=member) from None
                if (got := hashlib.sha256(data).hexdigest()) != digest:
                    raise DataError(f"sha256 {got}, expected {digest}", file=str(wheel), key=member)
                written.append(atomic_write_bytes(scenario_dir(out) / name, data))
    except zipfile.BadZipFile as err:
        raise DataError(f"not a wheel (zip): {err}", file=str(wheel)) from None
    return written


def fetch(out: str | os.PathLike,
          wheel: str | os.PathLike | None = None) -> tuple[list[Path], bool]:
    """The verified scenario files under ``out``, fetched (pip download, or ``wheel``) only when
    they are missing or do not match their hashes. Returns ``(paths, fetched)``."""
    out = require_folder(out)
    if (paths := verified(out)) is not None:
        return paths, False
    if wheel is not None:
        if not os.path.isfile(wheel):
            raise DataError("wheel not found", file=str(wheel))
        paths = extract(Path(wheel), out)
    else:
        with tempfile.TemporaryDirectory(prefix="igdrivsim-samples-") as tmp:
            paths = extract(download_wheel(Path(tmp)), out)
    atomic_write_json(out / RECORD, dict(
        source=PACKAGE, wheel=WHEEL, wheel_sha256=WHEEL_SHA256, terms=TERMS,
        files={name: dict(sha256=digest, womd_scenario_id=sid, member=member)
               for member, (name, digest, sid) in FILES.items()}), indent=2)
    return paths, True


def samples_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default=None, metavar="DIR",
                        help=f"folder for the samples (default: {default_dir()}, "
                             "i.e. $XDG_CACHE_HOME/igdrivsim/samples)")
    parser.add_argument("--wheel", default=None, metavar="PATH",
                        help=f"use this downloaded {WHEEL} instead of pip download (offline)")
    parser.add_argument("--json", action="store_true", help="one JSON line only")


def samples_command(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else default_dir()
    paths, fetched = fetch(out, args.wheel)
    if args.json:
        print(json.dumps(dict(dir=str(scenario_dir(out)), files=[str(p) for p in paths],
                              fetched=fetched, terms=TERMS)))
        return 0
    how = f"fetched from {PACKAGE}" if fetched else "already there"
    print(f"{len(paths)} real WOMD scenarios in {scenario_dir(out)} ({how}; sha256 verified)")
    print(f"terms: {TERMS}")
    print(f"use them: igdrivsim replay {scenario_dir(out)}; "
          f"bash scripts/reproduce.sh --samples {out}")
    return 0
