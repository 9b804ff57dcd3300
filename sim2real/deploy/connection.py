"""One arm connection: how a command reaches its arm, declared once.

``sim2real deploy``, ``adapt``, ``finetune``, ``sysid --record`` and ``arm`` take the arm from
their command line the same way: ``add_arm_options`` adds the options a command honours to its
parser, ``arm_connection`` builds the block from the parsed arguments, and the command passes
the block on whole (nothing copies its fields).

Each backend's own settings are a frozen, validated dataclass (``SimOptions``, ``MockOptions``,
``SerialOptions``), registered once in ``BACKENDS`` beside the function that builds it (a string
entry point, as Gymnasium registers envs: this module imports neither MuJoCo nor OpenCV). The
connection is their union plus the options every backend shares, so an option belongs to the
backends whose class declares it, and one rule refuses it anywhere else:
``--plant is for --backend mock, not 'serial'``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sim2real.errors import ConfigError, UnknownNameError

if TYPE_CHECKING:
    import numpy as np

    from hardware.plant import Plant
    from hardware.spec import ArmSpec
    from sim2real.deploy.policy_io import PolicyIO

PERCEPTIONS: tuple[str, ...] = ("cameras", "fk")
SIM_CLOCKS: tuple[str, ...] = ("lockstep", "realtime")  # sim_arm.CLOCKS, without MuJoCo
FIRMWARES: tuple[str, ...] = ("avr", "python")  # hardware.emulator.FIRMWARES, without importing it


def _why(text: str) -> dict[str, str]:
    """Field metadata: why an option is refused on another backend (appended to the error)."""
    return {"why": text}


# ---- each backend's own options -------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Validated:
    """Options that check themselves when made: every class along the MRO checks the fields it
    declares (its own ``validate``), so a union of option classes checks them all, once."""

    def __post_init__(self) -> None:
        self.validate_all()

    def validate_all(self) -> None:
        for cls in reversed(type(self).__mro__):
            own = vars(cls).get("validate")
            if own is not None:
                own(self)


@dataclass(frozen=True, kw_only=True)
class SimulatedOptions(Validated):
    """What every simulated arm (sim, mock) takes and a real one does not."""

    # a longer host and firmware watchdog (and serial reply timeout, 1/8 of it) than the spec's,
    # for simulations on a machine too loaded to hold the real ones (tests under pytest -n 2)
    watchdog_s: float | None = field(default=None, metadata=_why("a real arm keeps its spec's"))

    def validate(self) -> None:
        if self.watchdog_s is not None and not (
            math.isfinite(self.watchdog_s) and self.watchdog_s > 0
        ):
            raise ConfigError(f"--watchdog-s must be > 0, got {self.watchdog_s!r}")


@dataclass(frozen=True, kw_only=True)
class SimOptions(SimulatedOptions):
    """MuJoCo as the arm (``SimArm``), the truth as its percept."""

    # "realtime" lets physics run on with the wall clock, as a real arm does while the host
    # thinks; "lockstep" advances it one control period per command, as the env steps, whatever
    # the machine's load (bench/deploy_mock.py measures sim/env on it)
    sim_clock: str = "realtime"

    def validate(self) -> None:
        if self.sim_clock not in SIM_CLOCKS:
            raise UnknownNameError("sim clock", self.sim_clock, SIM_CLOCKS)


@dataclass(frozen=True, kw_only=True)
class MockOptions(SimulatedOptions):
    """The emulated firmware on a pty with MuJoCo physics and rendered cameras, each in a
    process of its own: the arm as it is (``plant``), not as the spec says."""

    plant: str | Path | None = field(
        default=None, metadata=_why("it is the mock arm's truth (use it with --backend mock)")
    )
    firmware: str = "python"  # the Python firmware model or the AVR binary in simavr
    camera_fps: float = 30.0
    camera_nice: int = 10  # the render process yields to the control loop
    mock_nice: int = 5  # the arm's process (emulator + physics) yields to the loop too
    mock_switch_interval_s: float | None = None  # the arm process's GIL switch interval
    # with realtime and the Python firmware: the arm's process at SCHED_FIFO below the loop
    mock_realtime: bool = True
    camera_fails_after_s: float | None = None  # fault injection: the cameras hang
    emulator_options: Mapping[str, Any] = field(default_factory=dict)

    def validate(self) -> None:
        if self.firmware not in FIRMWARES:
            raise UnknownNameError("firmware", self.firmware, FIRMWARES)
        if not 0 <= self.mock_nice <= 19:
            raise ConfigError(f"mock_nice {self.mock_nice} not in [0, 19] (a niceness)")
        if not 1.0 <= self.camera_fps <= 240.0:
            raise ConfigError(f"camera_fps {self.camera_fps} not in [1, 240]")


@dataclass(frozen=True, kw_only=True)
class SerialOptions(Validated):
    """A real arm on a serial port, with real cameras or forward kinematics for a percept."""

    port: str | None = None  # a device or a pyserial URL (socket://...)
    baud: int | None = None  # None: the protocol's
    perception: str = "cameras"  # cameras (stereo markers) | fk (forward kinematics)
    dry_run: bool = False  # read and log, send nothing

    def validate(self) -> None:
        if self.perception not in PERCEPTIONS:
            raise UnknownNameError("perception", self.perception, PERCEPTIONS)


# ---- the registry -----------------------------------------------------------------------------
Built = tuple[Any, Any, Any]  # (hardware.ArmBase, deploy.Perception, deploy.worlds.World)


@dataclass(frozen=True)
class Backend:
    """A backend: its options class, what it needs given, and where its builder lives."""

    name: str
    options: type
    entry_point: str  # "module:function" (spec, io, connection, stack) -> Built
    required: Mapping[str, str] = field(default_factory=dict)  # field -> an example value
    description: str = ""

    def __call__(
        self, spec: ArmSpec, io: PolicyIO, conn: ArmConnection, stack: contextlib.ExitStack
    ) -> Built:
        """Open the arm, its perception and its world; everything opened closes with ``stack``."""
        module, _, name = self.entry_point.partition(":")
        build: Callable[..., Built] = getattr(importlib.import_module(module), name)
        return build(spec, io, conn, stack)

    def owns(self, name: str) -> bool:
        return any(f.name == name for f in dataclasses.fields(self.options))


BACKENDS: dict[str, Backend] = {
    b.name: b
    for b in (
        Backend("sim", SimOptions, "sim2real.deploy.runner:build_sim",
                description="MuJoCo as the arm, ground-truth perception"),
        Backend("mock", MockOptions, "sim2real.deploy.runner:build_mock",
                description="the emulated firmware on a pty, MuJoCo physics, rendered cameras"),
        Backend("serial", SerialOptions, "sim2real.deploy.runner:build_serial",
                required={"port": "for example /dev/ttyUSB0"},
                description="a real arm on a serial port"),
    )
}  # fmt: skip


# ---- the connection ---------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class ArmConnection(SerialOptions, MockOptions, SimOptions):
    """How to reach the arm: the backend, the bus, the cameras and their calibration, and each
    backend's own options (an option another backend declares is refused in one line)."""

    backend: str = "mock"
    protocol: str = "s2r"
    joint_calibration: Path | None = None  # host-side servo calibration YAML
    cameras: tuple[int, int] = (0, 1)  # left, right cv2.VideoCapture indices
    stereo_calibration: Path | None = field(default=None, metadata={"flag": "--calibration"})
    registration: Path | None = None  # base_T_cam file (calibrate register)
    markers: Path | None = None  # marker layout YAML (a real rig); default: the mock rig's
    camera_timeout_s: float | None = None  # None: 1 s for real cameras, 5 s for the mock's
    # the control loop's thread at real-time priority (SCHED_FIFO) where the OS allows it
    realtime: bool = True

    def __post_init__(self) -> None:
        """The backend first, then every option's backend, then every value, then what the
        backend needs given: the first wrong thing is the one reported."""
        if self.backend not in BACKENDS:
            raise UnknownNameError("backend", self.backend, BACKENDS)
        backend = BACKENDS[self.backend]
        for option in _BACKEND_FIELDS:
            self._check_belongs(option, backend)
        from hardware.protocols import PROTOCOLS

        if self.protocol not in PROTOCOLS:
            raise UnknownNameError("protocol", self.protocol, PROTOCOLS)
        self.validate_all()
        if self.firmware != "python" and self.protocol != "s2r":
            raise ConfigError(f"--firmware {self.firmware} speaks s2r, not {self.protocol!r}")
        for name, example in getattr(backend, "required", {}).items():
            if not getattr(self, name):
                raise ConfigError(f"--backend {self.backend} needs {_flag(name)} ({example})")

    def _check_belongs(self, option: dataclasses.Field[Any], backend: Any) -> None:
        """An option set away from its default on a backend whose class does not declare it."""
        if option.default_factory is not dataclasses.MISSING:
            default = option.default_factory()
        else:
            default = option.default
        if getattr(self, option.name) == default:
            return
        if not isinstance(backend, Backend) or backend.owns(option.name):
            return  # a backend registered as a bare builder (tests) takes what it is given
        owners = "|".join(sorted(n for n, b in BACKENDS.items() if _owns(b, option.name)))
        why = option.metadata.get("why")
        raise ConfigError(
            f"{_flag(option.name)} is for --backend {owners}, not {self.backend!r}"
            + (f": {why}" if why else "")
        )

    def load_registration(self) -> np.ndarray | None:
        """The registration (base_T_cam of the left camera) or None: loaded by the builder that
        uses it, so a bad file fails there, before the arm moves."""
        if self.registration is None:
            return None
        from calibration.registration import load_base_T_cam

        return load_base_T_cam(self.registration)

    def require_cameras(self) -> None:
        """A real arm's stereo cameras need their calibration and registration."""
        if self.stereo_calibration is None or self.registration is None:
            raise ConfigError(
                "--backend serial needs --calibration (stereo) and --registration (base_T_cam)"
            )

    def require_backend(self, allowed: Collection[str]) -> None:
        """A command that runs on some backends only (adapt and finetune: mock, serial)."""
        if self.backend not in allowed:
            raise ConfigError(f"--backend {self.backend!r} is not one of {list(allowed)}")

    def relaxed_host(self) -> dict[str, Any]:
        """A simulated arm on a loaded machine (``watchdog_s``): the host's watchdog and the
        serial reply timeout (1/8 of it) relaxed with the firmware's; nothing otherwise."""
        if self.watchdog_s is None:
            return {}
        return {"host_watchdog_s": self.watchdog_s, "timeout_s": max(0.05, self.watchdog_s / 8)}

    def plant_for(self, spec: ArmSpec) -> Plant:
        """The mock arm as it is (``hardware.plant.Plant``): the given plant or the spec itself,
        checked against the spec, with the firmware watchdog of ``watchdog_s`` where given."""
        from hardware.plant import Plant, load_plant

        plant = Plant.nominal(spec) if self.plant is None else load_plant(self.plant)
        plant.check_against(spec)
        if self.watchdog_s is not None:  # the device's watchdog lives in the plant's firmware
            safety = dataclasses.replace(plant.spec.safety, watchdog_timeout_s=self.watchdog_s)
            plant = dataclasses.replace(plant, spec=dataclasses.replace(plant.spec, safety=safety))
        return plant


def _owns(backend: Any, name: str) -> bool:
    return isinstance(backend, Backend) and backend.owns(name)


# the options a backend's class declares (the rest are every backend's)
_BACKEND_FIELDS = tuple(
    f
    for f in dataclasses.fields(ArmConnection)
    if f.name not in vars(ArmConnection)["__annotations__"]
)


def _flag(name: str) -> str:
    meta = ArmConnection.__dataclass_fields__[name].metadata
    return str(meta.get("flag", "--" + name.replace("_", "-")))


# ---- the command line -------------------------------------------------------------------------
@dataclass(frozen=True)
class _Cli:
    """One command-line option of the connection: offered to a command on one of ``backends``;
    an ``extra`` only to a command that asks for it."""

    dest: str
    flags: tuple[str, ...]
    backends: tuple[str, ...]
    kwargs: Mapping[str, Any]
    extra: bool = False


_ALL = ("sim", "mock", "serial")
_OPTIONS: tuple[_Cli, ...] = (
    _Cli("port", ("--port",), ("serial",),
         {"help": "serial port or pyserial URL (/dev/ttyUSB0, socket://...)"}),
    _Cli("baud", ("--baud",), ("serial",), {"type": int, "help": "default: the protocol's"}),
    _Cli("joint_calibration", ("--joint-calibration",), ("serial", "mock"),
         {"type": Path, "help": "the arm's joint calibration YAML (sim2real arm calibrate)"}),
    _Cli("perception", ("--perception",), ("serial",),
         {"default": "cameras", "help": "serial: cameras (stereo markers) | fk (forward kinematics "
          "of the readings; the objects where the episode placed them, no cameras)"}, extra=True),
    _Cli("cameras", ("--cameras",), ("serial",),
         {"default": "0,1", "help": "left,right cv2.VideoCapture indices"}),
    _Cli("stereo_calibration", ("--calibration",), ("serial", "mock"),
         {"type": Path, "help": "stereo calibration file (calibrate stereo)"}),
    _Cli("registration", ("--registration",), ("serial", "mock"),
         {"type": Path, "help": "base_T_cam file (calibrate register)"}),
    _Cli("markers", ("--markers",), ("serial", "mock"), {"type": Path, "help": "marker layout "
         "YAML of a real rig (which plates and cube are set up); default: the mock rig's"},
         extra=True),
    _Cli("plant", ("--plant",), ("mock",), {"help": "mock: the arm as it really is (plant YAML or "
         "preset: mild, moderate, hard); the policy keeps --spec"}),
    _Cli("firmware", ("--firmware",), ("mock",), {"default": "python",
         "help": "mock: python (the firmware model) | avr (the arm3 .elf in simavr)"}, extra=True),
    _Cli("camera_fps", ("--camera-fps",), ("mock",),
         {"type": float, "default": 30.0, "help": "mock cameras' frame rate"}, extra=True),
    _Cli("watchdog_s", ("--watchdog-s",), ("mock", "sim"), {"type": float, "help": "mock/sim "
         "only: a longer watchdog than the spec's, for a machine too loaded to hold it (tests); "
         "a real arm always keeps the spec's"}),
    _Cli("sim_clock", ("--sim-clock",), ("sim",), {"default": "realtime", "help": "sim: realtime "
         "(physics runs on with the wall clock) or lockstep (one control period of physics per "
         "command, as in training, whatever the machine's load)"}),
    _Cli("dry_run", ("--dry-run",), ("serial",),
         {"action": "store_true", "help": "serial: read and log, send nothing"}, extra=True),
)  # fmt: skip
EXTRAS: frozenset[str] = frozenset(o.dest for o in _OPTIONS if o.extra)


def add_arm_options(
    parser: argparse.ArgumentParser,
    backends: Sequence[str] = _ALL,
    *,
    protocol: str = "s2r",
    extras: Collection[str] = (),
    only: Collection[str] | None = None,
) -> None:
    """The connection's options a command on ``backends`` honours: ``--backend`` (when there
    is a choice), ``--protocol``, and each option of those backends; the ``extras`` a command
    asks for (``EXTRAS``: deploy's); with ``only``, just those (sysid, arm: the bus).
    ``arm_connection`` builds the block from what was parsed."""
    from hardware.protocols import PROTOCOLS

    known = {o.dest for o in _OPTIONS}
    unknown = [b for b in backends if b not in BACKENDS] + [
        e for e in (*extras, *(only or ())) if e not in known
    ]
    if unknown:
        raise ConfigError(f"add_arm_options: unknown backends or options {unknown}")
    parser.set_defaults(arm_backends=tuple(backends))
    if len(backends) > 1:
        default = "mock" if "mock" in backends else backends[0]
        parser.add_argument(
            "--backend", default=default, help=f"{' | '.join(backends)} (default: {default})"
        )
    else:
        parser.set_defaults(backend=backends[0])
    parser.add_argument(
        "--protocol", default=protocol, choices=sorted(PROTOCOLS), help="servo protocol"
    )
    for option in _OPTIONS:
        offered = only is None or option.dest in only
        wanted = only is not None or not option.extra or option.dest in extras
        if offered and wanted and any(b in backends for b in option.backends):
            kwargs = dict(option.kwargs)
            if option.dest == "port" and tuple(backends) == ("serial",):
                kwargs["required"] = True
            parser.add_argument(*option.flags, dest=option.dest, **kwargs)


def _camera_pair(text: str) -> tuple[int, int]:
    try:
        cams = tuple(int(c) for c in text.split(","))
    except ValueError:
        raise ConfigError(f"--cameras {text!r} must be two integers like 0,1") from None
    if len(cams) != 2:
        raise ConfigError(f"--cameras {text!r} must name exactly two cameras")
    return cams[0], cams[1]


def arm_connection(args: argparse.Namespace) -> ArmConnection:
    """The block from a parser ``add_arm_options`` filled, each parsed option by its field's
    name. A backend the command does not run on is refused in one line."""
    backends: tuple[str, ...] = getattr(args, "arm_backends", _ALL)
    if args.backend in BACKENDS and args.backend not in backends:
        raise ConfigError(f"--backend {args.backend!r} is not one of {list(backends)}")
    values: dict[str, Any] = {
        f.name: getattr(args, f.name)
        for f in dataclasses.fields(ArmConnection)
        if getattr(args, f.name, None) is not None
    }
    if isinstance(values.get("cameras"), str):
        values["cameras"] = _camera_pair(values["cameras"])
    return ArmConnection(**values)
