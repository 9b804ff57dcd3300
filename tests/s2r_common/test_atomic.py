"""The one atomic writer: whole files or the old file, and sane permissions."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from s2r_common.atomic import atomic_write_bytes, atomic_write_text

REPO = Path(__file__).resolve().parents[2]


def test_replaces_whole_files_and_keeps_no_temp(tmp_path: Path) -> None:
    p = tmp_path / "sub" / "x.bin"
    atomic_write_bytes(p, b"old")
    atomic_write_text(p, "néw")
    assert p.read_bytes() == "néw".encode()
    assert [q.name for q in p.parent.iterdir()] == ["x.bin"]


def test_a_failed_write_leaves_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p = tmp_path / "x.yaml"
    atomic_write_text(p, "old")

    def fail(*_: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_text(p, "new")
    assert p.read_text() == "old"
    assert [q.name for q in tmp_path.iterdir()] == ["x.yaml"]


def test_new_files_are_0644_and_existing_modes_are_kept(tmp_path: Path) -> None:
    """mkstemp makes 0600 files: a calibration written by one user must stay readable."""
    new = atomic_write_text(tmp_path / "new.txt", "a")
    assert stat.S_IMODE(new.stat().st_mode) == 0o644
    kept = tmp_path / "kept.txt"
    kept.write_text("a")
    kept.chmod(0o640)
    atomic_write_text(kept, "b")
    assert stat.S_IMODE(kept.stat().st_mode) == 0o640


def test_hardware_and_calibration_share_it_without_importing_each_other() -> None:
    code = (
        "import sys, hardware.atomic, calibration.camera, s2r_common.atomic as a\n"
        "assert hardware.atomic.atomic_write is a.atomic_write\n"
        "import calibration.camera as c; assert c.atomic_write_text is a.atomic_write_text\n"
        "print(sorted(m for m in ('sim2real', 'mujoco', 'torch') if m in sys.modules))"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    assert out.stdout.strip() == "[]"
