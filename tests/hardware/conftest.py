"""Shared fixtures of the hardware tests: the spec, emulators that always get stopped, and the
firmware core compiled once per session with g++."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # emulated.py and other helpers import as plain modules
    sys.path.insert(0, str(HERE))

from hardware.emulator import Emulator  # noqa: E402
from hardware.spec import ArmSpec, load_spec  # noqa: E402

FIRMWARE = HERE.parents[1] / "hardware" / "firmware" / "arm3"


@pytest.fixture(scope="session")
def spec() -> ArmSpec:
    return load_spec()


@pytest.fixture(scope="session")
def quick_spec() -> ArmSpec:
    """The shipped spec with a short e-stop hold, so e-stop tests do not wait half a second."""
    s = load_spec()
    return replace(s, safety=replace(s.safety, hold_before_disable_s=0.05))


@pytest.fixture
def make_emulator() -> Iterator[Callable[..., Emulator]]:
    made: list[Emulator] = []

    def factory(*args: Any, **kwargs: Any) -> Emulator:
        emu = Emulator(*args, **kwargs)
        emu.start()
        made.append(emu)
        return emu

    yield factory
    for emu in made:
        emu.stop()


def _compile_cmd(out: Path, sources: list[Path], extra: list[str] | None = None) -> list[str]:
    cmd = ["g++", "-std=c++11", "-O1", "-Wall", "-Wextra", *(extra or []), "-o", str(out)]
    return cmd + [str(s) for s in sources]


@pytest.fixture(scope="session")
def firmware_build(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The firmware core's host test, sketch test and replayer, built with g++ (in parallel); the
    replayer twice: the committed header (bare PWM servos) and the pot build of the shipped spec
    (every actuator's potentiometer on an analog input)."""
    from hardware.firmware.limits import write_limits_header

    if shutil.which("g++") is None:
        pytest.skip("g++ is not installed: the firmware core cannot be compiled on this machine")
    out = tmp_path_factory.mktemp("arm3")
    pots_header = write_limits_header(out / "limits_pots.h", load_spec(), source="test pot build")
    core = [FIRMWARE / "src" / "arm3_core.cpp", FIRMWARE / "src" / "s2r_crc.cpp"]
    bins = {
        "test_core": [FIRMWARE / "tests" / "test_core.cpp", *core],
        "replay": [FIRMWARE / "tests" / "replay.cpp", *core],
        "replay_pots": [FIRMWARE / "tests" / "replay.cpp", *core],
        "test_sketch": [
            FIRMWARE / "tests" / "test_sketch.cpp",
            *core,
            FIRMWARE / "src" / "servo_pulses.cpp",
        ],
    }
    procs = {}
    for name, sources in bins.items():
        extra = ["-I", str(FIRMWARE / "tests" / "stubs")] if name == "test_sketch" else None
        if name == "replay_pots":
            extra = [f'-DARM3_LIMITS_HEADER="{pots_header}"']
        cmd = _compile_cmd(out / name, sources, extra)
        procs[name] = (cmd, subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True))
    try:
        for cmd, proc in procs.values():
            _, err = proc.communicate(timeout=300)
            if proc.returncode != 0:
                raise AssertionError(f"g++ failed: {' '.join(cmd)}\n{err}")
    finally:  # a failed or timed-out build leaves no compiler running
        for _, proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return {name: out / name for name in bins}
