"""``sim2real adapt``: real -> sim -> real in one command, as stages over one output folder.

Stages, in order (``STAGES``); each writes its files atomically into ``--out`` and, once they are
all written, is added to ``status.json`` with its figures. A run that stops (Ctrl-C, SIGTERM, an
error) keeps every finished stage; running again with the same ``--out`` continues at the first
stage not done (the fine-tune continues from its own last checkpoint).

0. ``zero_shot``: the original policy deployed on the arm, N episodes (the transfer table's
   "before" cell);
1. ``record``: a servo excitation (``sysid.record``) and a kinematic excitation with the wrist
   marker in view of both cameras (``adapt.excite``), or the given ``--logs``;
2. ``sysid``: the servo fit and the kinematic fit (joint zero offsets, link lengths, 1-sigma);
3. ``fit``: the fitted spec, a DR preset centred on the fit and the host-side joint calibration
   carrying the fitted offsets (``adapt.fitted`` says why the offsets live there);
4. ``finetune``: the policy's SB3 checkpoint trained on under the fitted spec and centred preset
   within ``--minutes`` of wall clock (``adapt.checkpoint``);
5. ``export``: ONNX with the fitted spec's fingerprint;
6. ``evaluate``: the adapted policy deployed on the same arm, N episodes, with the fitted spec and
   calibration (the "after" cell).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hardware.atomic import atomic_write_bytes, atomic_write_text
from hardware.spec import ArmSpec, load_spec
from sim2real.adapt.figures import (
    DeployFigures,
    EvaluateFigures,
    ExportFigures,
    FinetuneFigures,
    FitFigures,
    GivenLogsFigures,
    RecordFigures,
    StageFigures,
    StageResult,
    SysidFigures,
)
from sim2real.deploy.connection import ArmConnection
from sim2real.deploy.replayed import check_source
from sim2real.errors import ConfigError, RunDirError, Sim2RealError

if TYPE_CHECKING:
    from hardware.serial_arm import SerialArm
    from sim2real.adapt.excite import MarkerView

STATUS_FORMAT = 1
STAGES: tuple[str, ...] = (
    "zero_shot",
    "record",
    "sysid",
    "fit",
    "finetune",
    "export",
    "evaluate",
)
RUNS_ON = ("mock", "serial")  # the backends adapt records and deploys on
# PPO on the reach task ran 520 env steps/s on this 2-core CPU (runs/ship/reach-ppo-s0): the
# default step cap is what --minutes could do at that rate; the wall clock stops it first.
FINETUNE_STEPS_PER_S = 520.0
# What a re-run must agree on to continue a folder: anything else would mix two adaptations.
_IDENTITY = ("policy", "backend", "plant", "spec", "logs")


class DeployInterruptedError(Sim2RealError):
    """A deploy stage stopped cleanly on Ctrl-C / SIGTERM (the loop parked the arm)."""


@dataclass(frozen=True)
class AdaptOptions:
    policy: str
    out: Path
    arm: ArmConnection = field(default_factory=ArmConnection)  # the mock arm by default
    spec: str | None = None
    minutes: float = 10.0
    finetune_steps: int | None = None  # a cap on fine-tune env steps (default from --minutes)
    episodes: int = 20
    logs: tuple[Path, ...] = ()  # given logs instead of recording
    servo_rate_hz: float = 100.0
    kinematic_s: float = 60.0
    start_timeout_s: float = 10.0
    seed: int = 1_000_000
    placements: str = "loop"  # or "held-out": the deploys replay evaluate's placements
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.arm.require_backend(RUNS_ON)  # the connection checked its own options
        if self.arm.backend == "serial":
            self.arm.require_cameras()  # the kinematic excitation watches the wrist marker
        check_source(self.placements, self.arm.backend)
        if not (math.isfinite(self.minutes) and self.minutes > 0):
            raise ConfigError(f"--minutes must be > 0, got {self.minutes!r}")
        if self.finetune_steps is not None and self.finetune_steps < 1:
            raise ConfigError(f"--finetune-steps must be >= 1, got {self.finetune_steps}")
        if self.episodes < 1:
            raise ConfigError(f"--episodes must be >= 1, got {self.episodes}")
        if not (math.isfinite(self.kinematic_s) and 2.0 <= self.kinematic_s <= 600.0):
            raise ConfigError(f"--kinematic-s must be in [2, 600] s, got {self.kinematic_s!r}")
        if not (math.isfinite(self.servo_rate_hz) and 10.0 <= self.servo_rate_hz <= 500.0):
            raise ConfigError(f"--servo-rate must be in [10, 500] Hz, got {self.servo_rate_hz!r}")

    def identity(self) -> dict[str, Any]:
        return {
            "policy": self.policy,
            "backend": self.arm.backend,
            "plant": None if self.arm.plant is None else str(self.arm.plant),
            "spec": self.spec,
            "logs": [str(p) for p in self.logs],
        }


def _now() -> str:
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")


def wilson(successes: int, n: int) -> tuple[float, float]:
    from sim2real.evaluate.stats import wilson_interval

    lo, hi = wilson_interval(successes, n)
    return round(lo, 4), round(hi, 4)


class Adapter:
    """Runs the stages not yet done; ``report`` receives each stage's result as it ends (or,
    for a stage an earlier run finished, as it is read back)."""

    def __init__(
        self,
        opts: AdaptOptions,
        report: Callable[[StageResult], None],
        on_start: Callable[[str], None] = lambda stage: None,
    ) -> None:
        self.opts = opts
        self.on_start = on_start
        self.out = opts.out
        self.report = report
        self.spec = load_spec(opts.spec)
        self.status = self._load_status()  # the record, as status.json keeps it
        self.results = self._finished()  # the same, typed
        self._check_inputs()
        self._preload()

    @staticmethod
    def _preload() -> None:
        """Import the stages' modules before the first stage starts. Observed: a Ctrl-C landing
        in a stage's first imports (MuJoCo, SciPy) was handled cleanly, yet CPython then ended
        the process by SIGINT at exit (a shell still shows 130; a parent's Popen sees -2).
        Imported here, a stage spends its time in work, not imports. Torch and SB3 are left to
        the fine-tune: they cost seconds, and a command that fails its input checks never
        needs them."""
        import importlib

        for name in (
            "yaml",
            "hardware.joint_calibration",
            "hardware.plant",
            "hardware.serial_arm",
            "sim2real.randomization",
            "sim2real.sysid.fit",
            "sim2real.sysid.kinematics",
            "sim2real.sysid.record",
            "sim2real.adapt.excite",
            "sim2real.adapt.fitted",
        ):
            importlib.import_module(name)

    def _check_inputs(self) -> None:
        """Everything that can be wrong with the input, before the arm moves: the policy has a
        checkpoint, the plant fits the spec, the given logs are logs of the right kind."""
        from sim2real.adapt.checkpoint import resolve_source

        resolve_source(self.opts.policy)
        if self.opts.arm.plant is not None:
            self.opts.arm.plant_for(self.spec)  # loads and checks it against the spec
        if self.opts.logs and not self.done("record"):
            self._classify_logs()

    # ---- status -----------------------------------------------------------------------------
    @property
    def status_path(self) -> Path:
        return self.out / "status.json"

    def _load_status(self) -> dict[str, Any]:
        if not self.status_path.is_file():
            return {
                "format": STATUS_FORMAT,
                **self.opts.identity(),
                "stages_done": [],
                "figures": {},
                "created_utc": _now(),
            }
        try:
            status = json.loads(self.status_path.read_text())
            done = list(status["stages_done"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RunDirError(f"{self.status_path}: unreadable adapt status ({exc})") from None
        for key in _IDENTITY:
            if status.get(key) != self.opts.identity()[key]:
                raise ConfigError(
                    f"--out {str(self.out)!r} holds an adaptation with {key}={status.get(key)!r}, "
                    f"not {self.opts.identity()[key]!r}: choose a new --out or the same options"
                )
        unknown = [s for s in done if s not in STAGES]
        if unknown:
            raise RunDirError(f"{self.status_path}: unknown stages {unknown}")
        return dict(status)

    def _finished(self) -> dict[str, StageResult]:
        """The stages an earlier run finished, read back from ``status.json``."""
        results = {}
        for stage in self.status["stages_done"]:
            try:
                results[stage] = StageResult.from_json(stage, self.status["figures"][stage])
            except (KeyError, TypeError, ValueError) as exc:
                raise RunDirError(
                    f"{self.status_path}: unreadable figures of stage {stage} ({exc!r})"
                ) from None
        return results

    def _mark_done(self, result: StageResult) -> None:
        stage = result.stage
        self.results[stage] = result
        done = [s for s in self.status["stages_done"] if s != stage] + [stage]
        self.status["stages_done"] = [s for s in STAGES if s in done]
        self.status["figures"][stage] = result.to_json()
        self.status["updated_utc"] = _now()
        atomic_write_text(self.status_path, json.dumps(self.status, indent=1) + "\n")

    def done(self, stage: str) -> bool:
        return stage in self.status["stages_done"]

    # ---- running ----------------------------------------------------------------------------
    def run(self) -> dict[str, StageResult]:
        """Every stage not done, in order; the results of all stages."""
        self.out.mkdir(parents=True, exist_ok=True)
        if not self.status_path.is_file():
            atomic_write_text(self.status_path, json.dumps(self.status, indent=1) + "\n")
        for stage in STAGES:
            if self.done(stage):
                self.report(self.results[stage])
                continue
            self.on_start(stage)
            t0 = time.perf_counter()
            figures: StageFigures = getattr(self, f"_stage_{stage}")()
            result = StageResult(stage, figures, round(time.perf_counter() - t0, 2))
            self._mark_done(result)
            self.report(result)
        return {stage: self.results[stage] for stage in STAGES if stage in self.results}

    # ---- shared pieces ----------------------------------------------------------------------
    def _control_hz(self) -> float:
        from sim2real.adapt.checkpoint import resolve_source

        return float(resolve_source(self.opts.policy).config.get("control_hz", 20.0))

    def _deploy(self, policy: str, spec: ArmSpec, calibration: Path | None) -> DeployFigures:
        from sim2real.deploy.loop import LoopConfig
        from sim2real.deploy.replayed import placements
        from sim2real.deploy.runner import deploy

        o = self.opts
        arm = dataclasses.replace(o.arm, joint_calibration=calibration)  # before, or fitted
        config = LoopConfig(
            # the original policy's held-out episodes, before and after: the same objects
            placements=placements(o.placements, o.policy, o.episodes),
            rate_hz=self._control_hz(),
            episodes=o.episodes,
            seed=o.seed,
            start_timeout_s=o.start_timeout_s,
        )
        result = deploy(policy, spec, arm, config)
        if result.stopped_early is not None:
            if result.stopped_early.startswith("interrupted"):
                raise DeployInterruptedError(f"deploy of {policy!r} interrupted; the arm is parked")
            raise ConfigError(f"deploy of {policy!r} stopped early: {result.stopped_early}")
        n, k = len(result.episodes), result.successes
        return DeployFigures(
            episodes=n,
            successes=k,
            success_rate=round(k / max(n, 1), 4),
            success_wilson95=wilson(k, n),
            mean_final_distance_m=result.summary().mean_final_distance_m,
            watchdog_trips=result.watchdog_trips,
        )

    def _write_json(self, name: str, figures: StageFigures) -> Path:
        body = figures.to_json()  # JSON only where it is written
        return atomic_write_text(self.out / name, json.dumps(body, indent=1) + "\n")

    # ---- stages -----------------------------------------------------------------------------
    def _stage_zero_shot(self) -> DeployFigures:
        figures = self._deploy(self.opts.policy, self.spec, self.opts.arm.joint_calibration)
        self._write_json("zero_shot.json", figures)
        return figures

    def _stage_record(self) -> RecordFigures | GivenLogsFigures:
        rec = self.out / "record"
        if self.opts.logs:
            return self._take_logs(rec)
        from sim2real.sysid.record import save_log

        servo, kin = self._record_on_arm()
        seen = np.all(np.isfinite(kin["ee_marker_m"]), axis=1)
        save_log(self.out / RecordFigures.SERVO_LOG, servo)
        save_log(self.out / RecordFigures.KINEMATIC_LOG, kin)
        return RecordFigures(
            servo_periods=len(servo["t_s"]),
            kinematic_periods=len(kin["t_s"]),
            kinematic_s=self.opts.kinematic_s,
            marker_seen_rate=round(float(seen.mean()), 3),
            logs=(RecordFigures.SERVO_LOG, RecordFigures.KINEMATIC_LOG),
        )

    def _classify_logs(self) -> tuple[list[Path], list[Path]]:
        """Given logs: a log with ``t_cmd_s`` is a servo log, one with wrist-marker keys a
        kinematic one (a log may be both); each is loaded and checked."""
        servo, kin = [], []
        for p in self.opts.logs:
            try:
                keys = set(np.load(p).files)
            except FileNotFoundError:
                raise ConfigError(f"log {str(p)!r} does not exist") from None
            except (OSError, ValueError) as exc:
                raise ConfigError(f"log {str(p)!r} is not a readable npz file: {exc}") from None
            marker = bool(keys & {"ee_marker_m", "ee_est_m"})
            if "t_cmd_s" in keys:
                servo.append(p)
            if marker:
                kin.append(p)
            if "t_cmd_s" not in keys and not marker:
                raise ConfigError(
                    f"log {str(p)!r} is neither a servo excitation log (t_cmd_s) nor a log with "
                    "wrist-marker observations (ee_marker_m, or ee_est_m with ee_seen)"
                )
        if not servo:
            raise ConfigError("--logs has no servo excitation log (sysid --record writes one)")
        if not kin:
            raise ConfigError(
                "--logs has no log with wrist-marker observations (ee_marker_m, or ee_est_m with "
                "ee_seen): record one with both cameras on (sim2real deploy --log)"
            )
        from sim2real.sysid.fit import load_log
        from sim2real.sysid.kinematics import load_marker_logs

        for p in servo:
            load_log(p, self.spec.n_joints)
        load_marker_logs(kin, self.spec)  # too few marker observations fail here, in one line
        return servo, kin

    def _take_logs(self, rec: Path) -> GivenLogsFigures:
        """The given logs, copied into ``record/`` so the folder holds what was fitted."""
        servo, kin = self._classify_logs()
        names: dict[str, list[str]] = {"servo": [], "kinematics": []}
        for kind, paths in (("servo", servo), ("kinematics", kin)):
            for i, p in enumerate(paths):
                name = f"{kind}-{i}.npz"
                atomic_write_bytes(rec / name, Path(p).read_bytes())
                names[kind].append(f"record/{name}")
        return GivenLogsFigures(
            servo_logs=tuple(names["servo"]),
            kinematic_logs=tuple(names["kinematics"]),
            given=tuple(str(p) for p in self.opts.logs),
        )

    def _record_on_arm(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        from sim2real.adapt.excite import record_kinematic_excitation as kinematic
        from sim2real.sysid.record import record_excitation

        with contextlib.ExitStack() as stack:
            arm, view = self._open_for_recording(stack)
            try:
                servo = record_excitation(arm, self.opts.servo_rate_hz)
                kin, snaps = kinematic(arm, view, self.opts.kinematic_s)
                arm.park()
            except KeyboardInterrupt:
                with contextlib.suppress(Exception):  # a second Ctrl-C: torque off on close
                    arm.park()
                raise
        kin["ee_marker_m"] = view.markers_m(snaps)  # the mock renders here, the arm closed
        return servo, kin

    def _open_for_recording(self, stack: contextlib.ExitStack) -> tuple[SerialArm, MarkerView]:
        """The arm on its bus alone (the mock: the plant's emulator on a pty) and a view of
        its wrist marker, opened on ``stack``."""
        from hardware.serial_arm import SerialArm
        from sim2real.adapt.excite import CameraView, RenderedView

        conn = self.opts.arm
        view: MarkerView
        if conn.backend == "mock":
            plant = conn.plant_for(self.spec)  # its watchdog relaxed as the mock deploy's
            emulator = stack.enter_context(plant.emulator(conn.protocol))
            arm = SerialArm(
                self.spec, emulator.port, conn.protocol, calibration=conn.joint_calibration,
                **conn.relaxed_host(),
            )  # fmt: skip
            view = RenderedView(plant.spec, emulator)
        else:
            from calibration.triangulate import StereoRig
            from sim2real.deploy.frames import OpenCVStereoCameras, wait_first

            assert conn.port is not None and conn.stereo_calibration is not None
            base_T_left = conn.load_registration()
            assert base_T_left is not None
            stereo = StereoRig.load(conn.stereo_calibration)
            frames = OpenCVStereoCameras(conn.cameras, stereo.left.image_size)
            stack.callback(frames.close)
            frames.start()
            wait_first(frames, 10.0)
            arm = SerialArm(self.spec, conn.port, conn.protocol, conn.baud, conn.joint_calibration)
            view = CameraView(frames, stereo, base_T_left)
        stack.enter_context(arm)
        return arm, view

    def _record_paths(self) -> tuple[list[Path], list[Path]]:
        record = self.results["record"].figures
        assert isinstance(record, RecordFigures | GivenLogsFigures)
        servo, kinematic = record.log_names()
        return [self.out / n for n in servo], [self.out / n for n in kinematic]

    def _stage_sysid(self) -> SysidFigures:
        from sim2real.sysid.fit import fit_servo, load_log
        from sim2real.sysid.kinematics import fit_kinematics, load_marker_logs

        servo_logs, kin_logs = self._record_paths()
        trajs = [load_log(p, self.spec.n_joints) for p in servo_logs]
        servo, rms = fit_servo(trajs, self.spec, fit_droop=True)
        servo_figures = {k: float(v) for k, v in asdict(servo).items()}
        kin = fit_kinematics(load_marker_logs(kin_logs, self.spec), self.spec)
        body = {
            "servo": servo_figures,
            "servo_rms_rad": float(rms),
            "kinematics": {
                "values": kin.values.tolist(),
                "std": kin.std.tolist(),
                "covariance": kin.covariance.tolist(),
                "rms_m": kin.rms_m,
                "n_used": kin.n_used,
                "n_rejected": kin.n_rejected,
            },
        }
        atomic_write_text(self.out / "sysid.json", json.dumps(body, indent=1) + "\n")
        return SysidFigures(
            servo={k: round(v, 5) for k, v in servo_figures.items()},
            servo_rms_rad=round(float(rms), 5),
            kinematics=kin.as_dict(),
        )

    def _fits(self) -> tuple[Any, Any]:
        from sim2real.sysid.kinematics import KinematicFit
        from sim2real.sysid.model import ServoFit

        try:
            body = json.loads((self.out / "sysid.json").read_text())
            k = body["kinematics"]
            servo = ServoFit(**body["servo"])
            kin = KinematicFit(
                values=np.asarray(k["values"], dtype=float),
                std=np.asarray(k["std"], dtype=float),
                covariance=np.asarray(k["covariance"], dtype=float),
                rms_m=float(k["rms_m"]),
                n_used=int(k["n_used"]),
                n_rejected=int(k["n_rejected"]),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RunDirError(f"{self.out / 'sysid.json'}: unreadable ({exc})") from None
        return servo, kin

    def _stage_fit(self) -> FitFigures:
        import yaml

        from hardware.joint_calibration import ArmCalibration
        from sim2real.adapt.checkpoint import resolve_source
        from sim2real.adapt.fitted import centred_ranges, fitted_spec, offset_calibration
        from sim2real.randomization import DRConfig
        from sim2real.sysid.kinematics import describe, estimated_plant

        servo, kin = self._fits()
        src = resolve_source(self.opts.policy)
        control_hz = float(src.config.get("control_hz", 20.0))
        spec = fitted_spec(self.spec, servo, kin)
        ranges = centred_ranges(dict(src.config["dr_ranges"]), servo, kin, spec, control_hz)
        DRConfig.from_dict("adapt", ranges)  # validated before anything is written
        arm = self.opts.arm
        base = ArmCalibration.load(arm.joint_calibration) if arm.joint_calibration else None
        cal = offset_calibration(spec, arm.protocol, kin.joint_offset_rad, base)
        cal.check_spec(spec)
        cal.unit_limits(spec)  # the turned horns still reach every limit
        header = (
            f"ArmSpec {spec.name}: fitted by `sim2real adapt` (servo + kinematic fit)\n"
            + describe(kin)
            + "\njoint offsets: in joint_calibration.yaml beside this file (host-side)"
        )
        spec.to_yaml(self.out / "fitted.yaml", header=header)
        preset = (
            "# DR preset centred on the fit (sim2real adapt): the policy's training ranges with "
            "actuation and\n# kinematics narrowed about the fitted values (sim2real.adapt.fitted)\n"
            + yaml.safe_dump(ranges, sort_keys=True)
        )
        atomic_write_text(self.out / "fitted.dr.yaml", preset)
        cal.save(self.out / "joint_calibration.yaml")
        estimated_plant(spec, kin, max(0.0, -servo.droop_rad)).to_yaml(
            self.out / "fitted.plant.yaml",
            header="The arm as `sim2real adapt` estimated it (a plant file: --plant takes it)",
        )
        L0, L1 = self.spec.links, spec.links
        latency_lo, latency_hi = ranges["actuation"]["latency_steps"]
        return FitFigures(
            spec="fitted.yaml",
            dr_preset="fitted.dr.yaml",
            joint_calibration="joint_calibration.yaml",
            fingerprint=spec.fingerprint(),
            link_change_mm=tuple(
                round((getattr(L1, f) - getattr(L0, f)) * 1000, 2)
                for f in ("base_height_m", "upper_arm_m", "forearm_m")
            ),
            joint_offset_rad=tuple(round(float(v), 5) for v in kin.joint_offset_rad),
            dr_link_half_width_m=ranges["kinematics"]["link_length_delta_m"][1],
            dr_offset_half_width_rad=ranges["kinematics"]["joint_offset_rad"][1],
            dr_latency_steps=(latency_lo, latency_hi),
        )

    def _fitted(self) -> ArmSpec:
        return load_spec(self.out / "fitted.yaml")

    def _stage_finetune(self) -> FinetuneFigures:
        from sim2real.adapt.checkpoint import prepare_finetune_dir, resolve_source
        from sim2real.randomization import load_preset
        from sim2real.train.rundir import RunDir
        from sim2real.train.runner import resume

        o = self.opts
        spec = self._fitted()
        run_dir = self.out / "finetune"
        budget_s = o.minutes * 60.0
        rd = RunDir(run_dir)
        status = rd.read_status() if rd.status_path.is_file() else None
        ongoing = (
            status is not None
            and rd.has_config()
            and rd.read_config().get("spec_fingerprint") == spec.fingerprint()
            and rd.latest_checkpoint() is not None
        )
        if not ongoing:
            src = resolve_source(o.policy)
            steps = o.finetune_steps or max(1, int(budget_s * FINETUNE_STEPS_PER_S))
            preset = self.out / "fitted.dr.yaml"
            dr = load_preset(preset)
            prepare_finetune_dir(src, run_dir, spec, preset, dr.to_dict(), steps, budget_s)
            status = rd.read_status()
        assert status is not None
        start_steps = int(rd.read_config()["adapted_from"]["steps"])
        left_s = budget_s - float(status.get("wall_s", 0.0))
        if status.get("finished") or left_s <= 0:
            result_steps, wall = int(status["steps_done"]), float(status.get("wall_s", 0.0))
            rate, success = math.nan, None
        else:
            res = resume(run_dir, max_wall_s=left_s, progress=False)
            result_steps, wall, rate = res.steps_done, res.wall_s, res.steps_per_s
            success = res.train_success_rate
        return FinetuneFigures(
            run_dir="finetune",
            steps=result_steps - start_steps,
            wall_s=round(wall, 1),
            budget_s=budget_s,
            steps_per_s=round(rate, 1) if math.isfinite(rate) else None,
            train_success_rate=None if success is None else round(success, 3),
        )

    def _stage_export(self) -> ExportFigures:
        from sim2real.export.exporter import export_policy
        from sim2real.export.policy import load_policy

        out = self.out / "policy.onnx"
        export_policy(self.out / "finetune", "onnx", out)  # written atomically (onnx_io)
        meta = load_policy(out).meta
        fitted_spec = self._fitted()
        meta.check_spec(fitted_spec)
        fitted = fitted_spec.fingerprint()
        return ExportFigures("policy.onnx", out.stat().st_size, fitted)

    def _stage_evaluate(self) -> EvaluateFigures:
        after = self._deploy(
            str(self.out / "policy.onnx"), self._fitted(), self.out / "joint_calibration.yaml"
        )
        zero = self.results.get("zero_shot")
        before = None if zero is None else zero.figures
        assert before is None or isinstance(before, DeployFigures)
        figures = EvaluateFigures(
            **vars(after),
            zero_shot_success_rate=None if before is None else before.success_rate,
            zero_shot_wilson95=None if before is None else before.success_wilson95,
        )
        self._write_json("evaluate.json", figures)
        return figures


def summary_table(results: dict[str, StageResult]) -> str:
    """One line per stage: its headline figures."""
    keys = {
        "zero_shot": ("success_rate", "success_wilson95", "episodes"),
        "record": ("servo_periods", "kinematic_periods", "marker_seen_rate"),
        "sysid": ("latency_s", "time_constant_s", "max_speed_rad_s", "rms_m", "servo_rms_rad"),
        "fit": ("link_change_mm", "joint_offset_rad", "fingerprint"),
        "finetune": ("steps", "wall_s", "train_success_rate"),
        "export": ("bytes", "fingerprint"),
        "evaluate": ("success_rate", "success_wilson95", "zero_shot_success_rate"),
    }
    lines = [f"{'stage':10s} {'wall s':>8s}  figures"]
    for stage in STAGES:
        result = results.get(stage)
        if result is None:
            lines.append(f"{stage:10s} {'-':>8s}  not done")
            continue
        f = result.to_json()
        shown = ", ".join(f"{k}={f[k]}" for k in keys[stage] if k in f)
        lines.append(f"{stage:10s} {f.get('stage_wall_s', 0.0):8.1f}  {shown}")
    return "\n".join(lines)
