"""``sim2real sysid``: fit the servo model to logged trajectories, or record an excitation."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from sim2real.deploy.connection import add_arm_options, arm_connection
from sim2real.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("logs", nargs="*", type=Path, help="trajectory logs (.npz) to fit")
    parser.add_argument("--out", type=Path, default=None, help="write the updated ArmSpec here")
    parser.add_argument(
        "--spec", default=None, help="ArmSpec the logs came from (default: shipped)"
    )
    parser.add_argument("--droop", action="store_true", help="also fit gravity droop")
    parser.add_argument(
        "--control-hz",
        type=float,
        default=20.0,
        help="the policy's control rate: the DR preset's latency_steps are counted at it",
    )
    parser.add_argument(
        "--record", type=Path, default=None, help="run the excitation and write a log here"
    )
    # with --record: the arm to excite (the bus alone: no cameras, no joint calibration)
    add_arm_options(parser, ("mock", "serial"), protocol="feetech", only=("port", "plant"))
    parser.add_argument("--rate", type=float, default=100.0, help="excitation rate in Hz")
    parser.add_argument(
        "--kinematics",
        nargs="+",
        type=Path,
        default=None,
        metavar="LOG",
        help="also fit joint zero offsets and link lengths to these deploy logs (joint readings "
        "+ wrist marker); --out then gets the fitted links and <stem>.plant.yaml the offsets",
    )
    parser.add_argument("--json", action="store_true")


def _record(args: argparse.Namespace) -> int:
    from hardware.serial_arm import SerialArm
    from hardware.spec import load_spec
    from sim2real.sysid.record import record_excitation, save_log

    conn = arm_connection(args)
    spec = load_spec(args.spec)
    if conn.backend == "mock":
        from hardware.emulator.server import Emulator
        from hardware.plant import load_plant

        if conn.plant is not None:
            plant = load_plant(conn.plant)
            plant.check_against(spec)
            emulator = plant.emulator(conn.protocol)
        else:
            emulator = Emulator(spec, conn.protocol)
        with emulator as emu, SerialArm(spec, emu.port, conn.protocol) as arm:
            log = record_excitation(arm, args.rate)
    else:
        assert conn.port is not None  # the connection needs it for a serial arm
        with SerialArm(spec, conn.port, conn.protocol) as arm:
            log = record_excitation(arm, args.rate)
    save_log(args.record, log)
    print(json.dumps({"log": str(args.record), "periods": len(log["t_s"])}))
    return 0


def run(args: argparse.Namespace) -> int:
    if args.record is not None:
        if args.logs:
            raise ConfigError("give either LOG files to fit or --record, not both")
        return _record(args)
    if args.kinematics:
        return _run_with_kinematics(args)
    if not args.logs:
        raise ConfigError("no logs given: sim2real sysid LOG [LOG ...] --out spec.yaml")
    from hardware.spec import load_spec
    from sim2real.sysid.apply import write_outputs
    from sim2real.sysid.fit import fit_servo, load_log

    spec = load_spec(args.spec)
    trajs = [load_log(p, spec.n_joints) for p in args.logs]
    fit, rms = fit_servo(trajs, spec, fit_droop=args.droop)
    summary = {**asdict(fit), "rms_rad": rms, "logs": [str(p) for p in args.logs]}
    if args.out is not None:
        spec_path, preset = write_outputs(
            args.out, spec, fit, rms, [p.name for p in args.logs], args.control_hz
        )
        summary.update(spec=str(spec_path), dr_preset=str(preset))
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:18s} {value}")
    return 0


def _run_with_kinematics(args: argparse.Namespace) -> int:
    """Servo fit (when servo logs are given) and kinematic fit; every fit is done before the
    first file is written, and each file is written atomically."""
    import yaml

    from hardware.atomic import atomic_write_text
    from hardware.spec import load_spec
    from sim2real.sysid.apply import dr_centre, updated_spec
    from sim2real.sysid.fit import fit_servo, load_log
    from sim2real.sysid.kinematics import (
        describe,
        estimated_plant,
        fit_kinematics,
        load_marker_logs,
    )

    spec = load_spec(args.spec)
    observations = load_marker_logs(list(args.kinematics), spec)
    summary: dict[str, object] = {}
    servo_spec, droop, preset_text = spec, 0.0, None
    if args.logs:
        trajs = [load_log(p, spec.n_joints) for p in args.logs]
        fit, rms = fit_servo(trajs, spec, fit_droop=args.droop)
        servo_spec, droop = updated_spec(spec, fit), -fit.droop_rad
        preset_text = yaml.safe_dump(dr_centre(fit, servo_spec, args.control_hz), sort_keys=False)
        summary.update({**asdict(fit), "rms_rad": rms, "logs": [str(p) for p in args.logs]})
    kfit = fit_kinematics(observations, spec)
    summary["kinematics"] = kfit.as_dict()
    summary["kinematics_logs"] = [str(p) for p in args.kinematics]
    if args.out is not None:
        plant = estimated_plant(servo_spec, kfit, droop)
        sources = ", ".join(p.name for p in [*args.logs, *args.kinematics])
        header = (
            f"ArmSpec {plant.spec.name}: fitted by `sim2real sysid` to {sources}\n"
            + describe(kfit)
            + "\njoint offsets (physical = reading + offset): see the .plant.yaml beside this file"
        )
        plant_path = args.out.with_name(args.out.stem + ".plant.yaml")
        plant.to_yaml(
            plant_path,
            header="The arm as `sim2real sysid --kinematics` estimated it (a plant file: "
            "--plant takes it)\n" + describe(kfit),
        )
        if preset_text is not None:
            preset = args.out.with_name(args.out.stem + ".dr.yaml")
            atomic_write_text(
                preset,
                f"# DR preset centred on the sysid fit; use with --dr {preset}\n" + preset_text,
            )
            summary["dr_preset"] = str(preset)
        plant.spec.to_yaml(args.out, header=header)
        summary.update(spec=str(args.out), plant=str(plant_path))
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:18s} {value}")
    return 0
