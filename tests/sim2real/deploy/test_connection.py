"""The arm connection: each option declared once, each backend's options refused elsewhere in
one line, one parser function and one builder from parsed arguments for every command."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
from pathlib import Path

import pytest

from sim2real.deploy import connection
from sim2real.deploy.connection import (
    BACKENDS,
    ArmConnection,
    MockOptions,
    SerialOptions,
    SimOptions,
    add_arm_options,
    arm_connection,
)
from sim2real.errors import ConfigError, UnknownNameError

CLI = Path(__file__).parents[3] / "sim2real" / "cli"

# a value away from each backend option's default, to set it on the wrong backend
AWAY = {
    "watchdog_s": 2.0, "sim_clock": "lockstep", "plant": "hard", "firmware": "avr",
    "camera_fps": 60.0, "camera_nice": 3, "mock_nice": 7, "mock_switch_interval_s": 0.001,
    "mock_realtime": False, "camera_fails_after_s": 1.0, "emulator_options": {"seed": 1},
    "port": "/dev/ttyUSB0", "baud": 57600, "perception": "fk", "dry_run": True,
}  # fmt: skip


def _owned() -> list[tuple[str, str]]:
    """(option, a backend that does not declare it), for every backend's own option."""
    out = []
    for name in AWAY:
        for backend in BACKENDS.values():
            if not backend.owns(name):
                out.append((name, backend.name))
    return out


def test_every_backend_option_is_declared_by_a_backend_class_and_listed_here() -> None:
    shared = set(vars(ArmConnection)["__annotations__"])
    backend_options = {f.name for f in dataclasses.fields(ArmConnection)} - shared
    assert backend_options == set(AWAY)
    for options in (SimOptions, MockOptions, SerialOptions):
        assert options in ArmConnection.__mro__


@pytest.mark.parametrize(("option", "backend"), _owned())
def test_an_option_of_another_backend_is_refused_in_one_line(option: str, backend: str) -> None:
    needed = {"port": "/dev/null"} if backend == "serial" and option != "port" else {}
    with pytest.raises(ConfigError) as info:
        ArmConnection(backend=backend, **{option: AWAY[option]}, **needed)
    message = str(info.value)
    flag = "--calibration" if option == "stereo_calibration" else "--" + option.replace("_", "-")
    assert message.startswith(f"{flag} is for --backend "), message
    assert f"not {backend!r}" in message and "\n" not in message


def test_the_messages_commands_have_always_given() -> None:
    with pytest.raises(ConfigError, match="--perception is for --backend serial, not 'mock'"):
        ArmConnection(backend="mock", perception="fk")
    with pytest.raises(ConfigError, match="use it with --backend mock"):
        ArmConnection(backend="serial", port="/dev/null", plant="hard")
    with pytest.raises(ConfigError, match=r"needs --port \(for example /dev/ttyUSB0\)"):
        ArmConnection(backend="serial")
    with pytest.raises(UnknownNameError, match="unknown backend 'usb'; valid: mock, serial, sim"):
        ArmConnection(backend="usb")
    with pytest.raises(UnknownNameError, match="unknown firmware 'rp2040'"):
        ArmConnection(firmware="rp2040")
    with pytest.raises(ConfigError, match="--firmware avr speaks s2r, not 'feetech'"):
        ArmConnection(firmware="avr", protocol="feetech")
    with pytest.raises(UnknownNameError, match="unknown protocol 'dynamixel'"):
        ArmConnection(protocol="dynamixel")
    with pytest.raises(ConfigError, match="--watchdog-s must be > 0, got -1.0"):
        MockOptions(watchdog_s=-1.0)  # a backend's options check themselves alone too


def test_the_first_wrong_thing_is_the_one_reported() -> None:
    """The backend's own options first (``lidar`` is named, not the missing calibration)."""
    with pytest.raises(UnknownNameError, match="unknown perception 'lidar'"):
        ArmConnection(backend="serial", port="/dev/null", perception="lidar")


def test_the_registry_names_its_builders_and_the_emulators_firmwares() -> None:
    from hardware.emulator import FIRMWARES

    assert set(connection.FIRMWARES) == set(FIRMWARES)
    for backend in BACKENDS.values():
        module, _, name = backend.entry_point.partition(":")
        assert callable(getattr(importlib.import_module(module), name)), backend.entry_point


def _parse(argv: list[str], *backends: str, **kwargs: object) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arm_options(parser, backends or tuple(BACKENDS), **kwargs)  # type: ignore[arg-type]
    return parser.parse_args(argv)


def test_parsed_options_build_the_block() -> None:
    args = _parse(["--backend", "serial", "--port", "/dev/ttyACM0", "--protocol", "feetech",
                   "--baud", "1000000", "--cameras", "2,3", "--calibration", "s.yaml",
                   "--registration", "r.yaml", "--joint-calibration", "j.yaml"])  # fmt: skip
    conn = arm_connection(args)
    assert (conn.backend, conn.port, conn.protocol, conn.baud) == (
        "serial", "/dev/ttyACM0", "feetech", 1000000
    )  # fmt: skip
    assert conn.cameras == (2, 3) and conn.stereo_calibration == Path("s.yaml")
    assert conn.registration == Path("r.yaml") and conn.joint_calibration == Path("j.yaml")
    assert arm_connection(_parse([])) == ArmConnection()  # the defaults are the block's


@pytest.mark.parametrize(
    ("cameras", "message"),
    [("a,b", "must be two integers like 0,1"), ("0,1,2", "must name exactly two cameras")],
)
def test_a_bad_camera_list_is_one_line(cameras: str, message: str) -> None:
    with pytest.raises(ConfigError, match=f"--cameras '{cameras}' {message}"):
        arm_connection(_parse(["--backend", "serial", "--port", "p", "--cameras", cameras]))


def test_a_command_offers_only_what_it_runs_on() -> None:
    args = _parse(["--backend", "sim"], "mock", "serial")
    with pytest.raises(ConfigError, match=r"--backend 'sim' is not one of \['mock', 'serial'\]"):
        arm_connection(args)
    with pytest.raises(SystemExit):  # sysid's bus: no cameras offered
        _parse(["--calibration", "s.yaml"], "mock", "serial", only=("port", "plant"))
    args = _parse(["--port", "/dev/ttyUSB0"], "serial", only=("port", "baud"))
    assert arm_connection(args).backend == "serial"  # one backend: no --backend flag
    with pytest.raises(SystemExit):
        _parse([], "serial", only=("port",))  # --port is required where only serial runs
    with pytest.raises(ConfigError, match="unknown backends or options"):
        _parse([], "serial", extras=("colour",))


def _declared_flags(path: Path) -> set[str]:
    flags = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "add_argument"
        ):
            flags |= {a.value for a in node.args if isinstance(a, ast.Constant)}
    return flags


@pytest.mark.parametrize("module", ["deploy", "adapt", "finetune", "sysid", "arm"])
def test_the_commands_that_reach_an_arm_compose_the_connection(module: str) -> None:
    """None of them declares a connection option itself (``arm emulate`` serves an arm: its
    --protocol, --baud and --plant are the emulated device's)."""
    source = (CLI / f"{module}.py").read_text()
    assert "add_arm_options(" in source and "arm_connection(" in source
    own = _declared_flags(CLI / f"{module}.py")
    connection_flags = {"--port", "--cameras", "--registration", "--watchdog-s", "--sim-clock"}
    assert not own & connection_flags, own & connection_flags
