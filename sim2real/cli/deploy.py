"""``sim2real deploy``: run a trained policy of any task on a simulated, emulated or real arm."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from sim2real.deploy.replayed import PLACEMENT_SOURCES
from sim2real.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "policy", help="a run directory, an exported .onnx / .npz policy, or a shipped policy name"
    )
    parser.add_argument("--backend", default="mock", help="sim | mock | serial (default: mock)")
    parser.add_argument("--protocol", default="s2r", help="s2r | feetech | maestro")
    parser.add_argument("--port", default=None, help="serial port or pyserial URL (serial)")
    parser.add_argument("--baud", type=int, default=None)
    parser.add_argument("--joint-calibration", type=Path, default=None, help="arm calibration YAML")
    parser.add_argument(
        "--perception", default="cameras", help="serial: cameras (stereo markers) | fk (forward "
        "kinematics of the readings; the objects where the episode placed them, no cameras)"
    )  # fmt: skip
    parser.add_argument("--cameras", default="0,1", help="left,right cv2.VideoCapture indices")
    parser.add_argument("--calibration", type=Path, default=None, help="stereo calibration file")
    parser.add_argument(
        "--registration", type=Path, default=None, help="base_T_cam file (calibrate register)"
    )
    parser.add_argument(
        "--markers", type=Path, default=None, help="marker layout YAML of a real rig (which "
        "plates and cube are set up); default: the mock rig's"
    )  # fmt: skip
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped arm)")
    parser.add_argument(
        "--plant", default=None, help="mock: the arm as it really is (plant YAML or preset: "
        "mild, moderate, hard); the policy keeps --spec"
    )  # fmt: skip
    parser.add_argument("--firmware", default="python", help="mock: python | avr (simavr)")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument(
        "--steps", type=int, default=None, help="control periods per episode (default: training's)"
    )
    parser.add_argument("--rate", type=float, default=20.0, help="control rate in Hz")
    parser.add_argument("--camera-fps", type=float, default=30.0, help="mock cameras' frame rate")
    parser.add_argument("--seed", type=int, default=1_000_000, help="placement seed (held out)")
    parser.add_argument(
        "--placements", default="loop", choices=tuple(PLACEMENT_SOURCES),
        help="sim/mock: where the objects go: the loop's own draws (--seed), or the policy's "
        "held-out evaluation episodes (evaluate --dr none places the same objects)",
    )  # fmt: skip
    parser.add_argument(
        "--start-timeout", type=float, default=10.0,
        help="seconds an episode waits for its objects to be seen and still",
    )  # fmt: skip
    parser.add_argument(
        "--watchdog-s", type=float, default=None,
        help="mock/sim only: a longer watchdog than the spec's, for a machine too loaded to "
        "hold it (tests); a real arm always keeps the spec's",
    )  # fmt: skip
    parser.add_argument(
        "--sim-clock", default="realtime",
        help="sim: realtime (physics runs on with the wall clock) or lockstep (one control "
        "period of physics per command, as in training, whatever the machine's load)",
    )  # fmt: skip
    parser.add_argument("--dry-run", action="store_true", help="serial: read and log, send nothing")
    parser.add_argument("--log", type=Path, default=None, help="trajectory log (.npz)")
    parser.add_argument("--video", type=Path, default=None, help="mp4 of the left camera")
    parser.add_argument(
        "--record-dataset", type=Path, default=None, metavar="DIR",
        help="write the episodes as a LeRobot dataset (v3.0; both cameras as videos)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("-v", "--verbose", action="store_true")


def _load_base_T_cam(path: Path) -> np.ndarray:
    from calibration.registration import load_base_T_cam

    return load_base_T_cam(path)


def run(args: argparse.Namespace) -> int:
    from hardware.spec import load_spec
    from sim2real.deploy.loop import LoopConfig
    from sim2real.deploy.replayed import check_source, placements
    from sim2real.deploy.runner import DeployOptions, deploy

    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s"
    )
    try:
        cams = tuple(int(c) for c in args.cameras.split(","))
    except ValueError:
        raise ConfigError(f"--cameras {args.cameras!r} must be two integers like 0,1") from None
    if len(cams) != 2:
        raise ConfigError(f"--cameras {args.cameras!r} must name exactly two cameras")
    spec = load_spec(args.spec)
    opts = DeployOptions(
        backend=args.backend,
        perception=args.perception,
        protocol=args.protocol,
        port=args.port,
        baud=args.baud,
        joint_calibration=args.joint_calibration,
        cameras=(cams[0], cams[1]),
        stereo_calibration=args.calibration,
        base_T_left=_load_base_T_cam(args.registration) if args.registration else None,
        markers=args.markers,
        dry_run=args.dry_run,
        camera_fps=args.camera_fps,
        plant=args.plant,
        firmware=args.firmware,
        watchdog_s=args.watchdog_s,
        sim_clock=args.sim_clock,
    )
    check_source(args.placements, args.backend)
    config = LoopConfig(
        placements=placements(args.placements, args.policy, args.episodes),
        rate_hz=args.rate,
        episodes=args.episodes,
        episode_steps=args.steps,
        seed=args.seed,
        dry_run=args.dry_run,
        start_timeout_s=args.start_timeout,
    )
    if args.record_dataset is not None and args.record_dataset.exists():
        raise ConfigError(f"--record-dataset {str(args.record_dataset)!r} exists; choose a new one")
    result = deploy(
        args.policy, spec, opts, config, log_path=args.log, video_path=args.video,
        dataset_path=args.record_dataset,
    )  # fmt: skip
    summary = {"backend": args.backend, **result.summary()}
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:22s} {value}")
    return 0 if result.stopped_early is None else 1
