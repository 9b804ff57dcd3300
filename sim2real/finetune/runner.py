"""``sim2real finetune``: learn on the arm, the deploy loop with a learner beside it.

The loop process steps ``ArmEnv`` at the control rate with a numpy copy of the actor (inference
only) and sends every transition to the learner process (``finetune.learner``), which holds the
SB3 model, the replay buffer(s), the critic and the optimisers and publishes the actor back every
N env steps; the loop takes new weights between periods and never waits for them.

Between episodes (the env holds the arm on its own thread) the loop writes the episode's deploy
log, checks the learner, and every K episodes asks it for a checkpoint: model, optimisers and
the online transitions, then the counters (``finetune.checkpoint.FinetuneDir``). Ctrl-C, SIGTERM
and the e-stop key end the same way: the arm parks (or stays held, torque off, after an e-stop),
the learner checkpoints everything sent so far, and the learner process is stopped; ``--resume``
continues from there, losing at most the episode in flight.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hardware.errors import HardwareError, NoReplyError, StallError, TorqueOffError
from hardware.spec import ArmSpec
from sim2real.deploy.runner import DeployOptions
from sim2real.errors import ConfigError
from sim2real.finetune.checkpoint import ALGOS, FinetuneDir, FinetuneSource, resolve
from sim2real.finetune.defaults import ACTOR_UPDATES, LEARNER_DEFAULTS
from sim2real.finetune.relabel import default_ratio
from sim2real.finetune.results import EvalFigures, FinetuneSummary, LoopFigures

log = logging.getLogger(__name__)

Report = Callable[[dict[str, Any]], None]
MAX_CONSECUTIVE_TRIPS = 3  # watchdog trips in a row that a simulated arm recovers from
# The source's own anchor (``ddpg_pick``'s 100 imitation minibatches per 200 updates): a DAgger
# source keeps it on the arm, its teacher the source actor (finetune has no privileged state).
DAGGER_ANCHOR_RATIO = 0.5
RETRY_SEED_STRIDE = 1_000_003  # a retried episode's seed offset (beyond any run's episode count)


@dataclass(frozen=True)
class FinetuneOptions:
    """What ``sim2real finetune`` was asked to do (the arm's own options are ``deploy``)."""

    policy: str
    out: Path
    deploy: DeployOptions
    minutes: float = 15.0  # arm time (episodes, resets included) this invocation may use
    algo: str | None = None  # None: the source's
    mix_sim_buffer: bool = False
    sim_buffer_steps: int = 5000
    resume: bool = False
    keys: bool | None = None  # None: when stdin is a terminal
    checkpoint_every: int = 1  # episodes
    learning_starts: int = int(
        LEARNER_DEFAULTS["learning_starts"]
    )  # before the first gradient step
    utd: float = float(LEARNER_DEFAULTS["utd"])  # gradient steps per online transition
    actor_starts: int = int(LEARNER_DEFAULTS["actor_starts"])  # online transitions: critic only
    learning_rate: float | None = None  # None: the source run's
    noise_std: float | None = None  # DDPG/TD3 exploration std (normalised actions); None: default
    noise_corr_steps: float = 0.0  # 0: white noise; else AR(1) with this correlation time
    gripper_noise_std: float | None = None  # the gripper's own exploration std; None: noise_std
    relabel: float | None = None  # hindsight-goal share of a batch; None: the task's default
    # imitation minibatches towards the source actor per gradient step; None: the source's
    # (DAGGER_ANCHOR_RATIO where it was trained with a DAgger anchor, else none)
    anchor: float | None = None
    actor_update: str = "critic"  # ``learner.ACTOR_UPDATES``
    imitation_ratio: float = 1.0  # "success", "advantage": imitation minibatches per step
    publish_every: int = 20  # env steps between weight publications
    batch_size: int | None = None
    learner_nice: int = 10
    success_window: int = 20  # the success rate over the last N episodes
    eval_every_min: float | None = None  # deterministic evaluation blocks, every M arm minutes
    eval_episodes: int = 10
    max_episodes: int | None = None  # a cap for this invocation (tests, benches)
    seed: int = 0
    start_timeout_s: float = 10.0
    record_dataset: Path | None = None

    def __post_init__(self) -> None:
        if self.deploy.backend not in ("mock", "serial", "sim"):
            raise ConfigError(f"--backend {self.deploy.backend!r} is not mock or serial")
        if not (math.isfinite(self.minutes) and self.minutes > 0):
            raise ConfigError(f"--minutes must be > 0, got {self.minutes!r}")
        if self.algo is not None and self.algo not in ALGOS:
            raise ConfigError(f"--algo {self.algo!r} is not one of {list(ALGOS)}")
        for name in ("checkpoint_every", "publish_every", "eval_episodes", "success_window"):
            if getattr(self, name) < 1:
                raise ConfigError(f"--{name.replace('_', '-')} must be >= 1")
        if self.actor_update not in ACTOR_UPDATES:
            raise ConfigError(
                f"--actor-update {self.actor_update!r} is not one of {sorted(ACTOR_UPDATES)}"
            )
        if not (math.isfinite(self.imitation_ratio) and self.imitation_ratio > 0):
            raise ConfigError(
                f"--imitation-ratio must be a number > 0, got {self.imitation_ratio!r}"
            )
        if self.anchor is not None and not (math.isfinite(self.anchor) and self.anchor >= 0):
            raise ConfigError(f"--anchor must be a number >= 0, got {self.anchor!r}")
        if self.noise_std is not None and not (
            math.isfinite(self.noise_std) and 0 <= self.noise_std <= 1
        ):
            raise ConfigError(f"--noise-std must be in [0, 1], got {self.noise_std!r}")
        if not (math.isfinite(self.noise_corr_steps) and self.noise_corr_steps >= 0):
            raise ConfigError(f"--noise-corr-steps must be >= 0, got {self.noise_corr_steps!r}")
        if self.gripper_noise_std is not None and not (
            math.isfinite(self.gripper_noise_std) and 0 <= self.gripper_noise_std <= 2
        ):
            raise ConfigError(
                f"--gripper-noise-std must be in [0, 2], got {self.gripper_noise_std!r}"
            )
        if self.actor_starts < 0:
            raise ConfigError(f"--actor-starts must be >= 0, got {self.actor_starts}")
        if self.relabel is not None and not (
            math.isfinite(self.relabel) and 0 <= self.relabel <= 1
        ):
            raise ConfigError(f"--relabel must be in [0, 1], got {self.relabel!r}")
        if self.learning_rate is not None and not (
            math.isfinite(self.learning_rate) and 0 < self.learning_rate < 1
        ):
            raise ConfigError(f"--learning-rate must be in (0, 1), got {self.learning_rate!r}")
        if self.learning_starts < 1 or self.sim_buffer_steps < 1:
            raise ConfigError("--learning-starts and --sim-buffer-steps must be >= 1")
        if not (math.isfinite(self.utd) and 0 < self.utd <= 64):
            raise ConfigError(f"--utd must be in (0, 64], got {self.utd!r}")
        if self.eval_every_min is not None and not self.eval_every_min > 0:
            raise ConfigError(f"--eval-every must be > 0 arm minutes, got {self.eval_every_min}")
        if self.max_episodes is not None and self.max_episodes < 1:
            raise ConfigError(f"--max-episodes must be >= 1, got {self.max_episodes}")
        if not 0 <= self.learner_nice <= 19:
            raise ConfigError(f"--learner-nice {self.learner_nice} not in [0, 19]")
        if self.record_dataset is not None and self.record_dataset.exists():
            raise ConfigError(
                f"--record-dataset {str(self.record_dataset)!r} exists; choose a new one"
            )


def _fresh_state(identity: dict[str, Any]) -> dict[str, Any]:
    return {
        "format": 1,
        **identity,
        "env_steps": 0,
        "episodes": 0,
        "arm_s": 0.0,
        "wall_s": 0.0,
        "learner_updates": 0,
        "segments": 0,
        "checkpoint": None,
        "episode_log": [],
        "evals": [],
        "interventions": [],
        "stops": [],
    }


class _Run:
    """One invocation: the learner, the env, the counters."""

    def __init__(self, fo: FinetuneOptions, spec: ArmSpec, report: Report) -> None:
        self.fo, self.spec, self.report = fo, spec, report
        self.src: FinetuneSource = resolve(fo.policy, fo.algo)
        self.algo = fo.algo or self.src.algo
        # what explores and what is relabelled: the options, or the defaults where left unset
        self.noise_std = float(
            LEARNER_DEFAULTS["noise_std"] if fo.noise_std is None else fo.noise_std
        )
        self.relabel = default_ratio(self.src.config) if fo.relabel is None else fo.relabel
        self.anchor = default_anchor(self.src.config) if fo.anchor is None else fo.anchor
        if fo.gripper_noise_std is not None and spec.gripper is None:
            raise ConfigError(
                f"--gripper-noise-std {fo.gripper_noise_std:g}: arm {spec.name!r} has no gripper"
            )
        self.dir = FinetuneDir(fo.out)
        opts = fo.deploy
        plant = None if opts.plant is None else str(opts.plant)
        self.identity = {
            "source": fo.policy,
            "algo": self.algo,
            "backend": opts.backend,
            "plant": plant,
            "spec_fingerprint": spec.fingerprint(),
        }
        state = self.dir.start(self.identity, fo.resume)
        self.resumed = state is not None
        self.state = state if state is not None else _fresh_state(self.identity)
        self.state["segments"] = int(self.state.get("segments", 0)) + 1
        self.state["finished"] = False
        self.stop_reason: str | None = None
        self.start_episodes = int(self.state["episodes"])
        self.start_arm_s = float(self.state["arm_s"])
        self.watchdog_trips = 0
        self._consecutive_trips = 0
        self.weight_updates = 0
        self.wall_t0 = time.monotonic()
        self.wall_before = float(self.state.get("wall_s", 0.0))

    # ---- the learner ------------------------------------------------------------------------
    def learner_config(self) -> Any:
        from sim2real.finetune.learner import Learner, LearnerConfig, SimBufferConfig
        from sim2real.finetune.relabel import goal_fields

        fo, src = self.fo, self.src
        ratio = self.relabel
        model_zip, replay = str(src.model_zip), None
        if self.resumed:
            ckpt = self.dir.run.checkpoint_dir / str(self.state["checkpoint"])
            model_zip = str(ckpt)
            npz = ckpt.with_name(ckpt.stem + ".replay.npz")
            replay = str(npz) if npz.is_file() else None
        sim = None
        if fo.mix_sim_buffer:
            sim = SimBufferConfig(
                env_id=str(src.config["env_id"]),
                env_kwargs=dict(src.config.get("env_kwargs", {})),
                spec=self.spec,
                steps=fo.sim_buffer_steps,
                seed=fo.seed + 7919 * int(self.state["segments"]),
            )
        return LearnerConfig(
            algo=self.algo,
            source_algo=src.algo,
            model_zip=model_zip,
            obs_stats=src.obs_stats,
            replay_npz=replay,
            resume=self.resumed,
            batch_size=fo.batch_size,
            learning_starts=fo.learning_starts,
            utd=fo.utd,
            actor_starts=fo.actor_starts,
            learning_rate=fo.learning_rate,
            action_rate_penalty=Learner.action_rate_penalty(src.config),
            publish_every=fo.publish_every,
            nice=fo.learner_nice,
            seed=fo.seed + int(self.state["segments"]),
            sim_buffer=sim,
            relabel_ratio=ratio,
            goal_fields=goal_fields(src.config) if ratio > 0 else None,
            anchor_ratio=self.anchor,
            anchor_zip=str(src.model_zip) if self.anchor > 0 else None,
            actor_update=fo.actor_update,
            imitation_ratio=fo.imitation_ratio,
        )

    def checkpoint(self, learner: Any, final: bool = False) -> None:
        model_ckpt, replay = self.dir.checkpoint_files(int(self.state["env_steps"]))
        updates, online = learner.checkpoint(
            [str(model_ckpt), str(self.dir.run.model_path)], str(replay)
        )
        self.state.update(
            checkpoint=model_ckpt.name,
            learner_updates=updates - int(self.state.get("updates_base", 0)),
            online_transitions=online,
            wall_s=self.wall_before + time.monotonic() - self.wall_t0,
            finished=final,
        )
        self.dir.write_checkpoint_meta(
            self.src, self.algo, self.state, self.fo.deploy.backend, self.identity["plant"]
        )

    # ---- the loop -----------------------------------------------------------------------------
    def run(self) -> FinetuneSummary:
        from sim2real.finetune.actor import NumpyActor, ObsNormalizer
        from sim2real.finetune.learner import LearnerHandle

        if not self.resumed:
            self.dir.write_static(self.src, self.spec)
        with contextlib.ExitStack() as stack:
            # before anything real-time or any port: the learner must not inherit either
            learner = LearnerHandle(self.learner_config())
            stack.callback(learner.close)
            info = learner.wait_ready()
            normalizer = ObsNormalizer.from_stats(self.src.obs_stats)
            actor = NumpyActor(info["kind"], info["shapes"], learner.initial_weights(),
                               normalizer, self.noise_std, self.fo.noise_corr_steps,
                               self.fo.gripper_noise_std)  # fmt: skip
            self.report({"event": "learner_ready", "algo": self.algo,
                         **info, "noise_std": self.noise_std,  # what explores, not the source's
                         "learner_pid": learner.pid, "resumed": self.resumed,
                         "env_steps": self.state["env_steps"],
                         "episodes": self.state["episodes"]})  # fmt: skip
            if not self.resumed:
                self.state["updates_base"] = int(info["updates"])  # the sim run's own updates
                self.checkpoint(learner)  # step 0: the folder is a run dir from the start
            human = self._human(stack)
            env = self._env(human)
            stack.callback(env.close)
            recorder = self._recorder(env, stack)
            try:
                self._episodes(env, learner, actor, normalizer, human, recorder)
            except BaseException as exc:
                self.stop_reason = _why(exc)
                self.state["stops"].append(
                    {"reason": self.stop_reason, "episode": self.state["episodes"],
                     "env_steps": self.state["env_steps"]}
                )  # fmt: skip
                self.watchdog_trips += int(_tripped(exc))
                env.close()  # the arm first: parked (or held, torque off, after an e-stop)
                end = env.end_state
                self.state["stops"][-1]["arm_end"] = {} if end is None else end.to_json()
                self._interventions(human)
                if not isinstance(exc, _learner_errors()):
                    try:
                        self.checkpoint(learner)
                    except Exception as ckpt_exc:  # the last good checkpoint stands
                        log.error("no checkpoint at the stop: %s", ckpt_exc)
                if recorder is not None:
                    recorder.close()
                from sim2real.deploy.loop import DeployStopError

                if isinstance(exc, DeployStopError):  # the e-stop key: a clean stop
                    return self.summary(env, learner)
                raise
            env.close()
            self._interventions(human)
            self.checkpoint(learner, final=True)
            if recorder is not None:
                recorder.close()
            return self.summary(env, learner)

    def _human(self, stack: contextlib.ExitStack) -> Any:
        keys = self.fo.keys if self.fo.keys is not None else sys.stdin.isatty()
        if not keys:
            return None
        from sim2real.finetune.keys import HumanKeys

        human = HumanKeys(sys.stdin.fileno())
        stack.enter_context(human)
        return human

    def _env(self, human: Any) -> Any:
        from sim2real.finetune.arm_env import ArmEnv, ArmEnvConfig

        rate = float(self.src.config.get("control_hz", 20.0))
        config = ArmEnvConfig(rate_hz=rate, start_timeout_s=self.fo.start_timeout_s)
        return ArmEnv.for_policy(self.fo.policy, self.spec, self.fo.deploy, config, human)

    def _recorder(self, env: Any, stack: contextlib.ExitStack) -> Any:
        if self.fo.record_dataset is None:
            return None
        from sim2real.deploy.perception import StereoPerception
        from sim2real.deploy.recording import DeployRecorder

        cameras = isinstance(env.perception, StereoPerception)
        recorder = DeployRecorder(
            self.fo.record_dataset, self.spec, env.io, env.config.rate_hz, cameras
        )
        return recorder

    def _episodes(
        self, env: Any, learner: Any, actor: Any, normalizer: Any, human: Any, recorder: Any
    ) -> None:
        from sim2real.deploy.loop import LoopLog
        from sim2real.deploy.realtime import QuietGC, control_thread_priority, single_threaded_blas

        fo, st = self.fo, self.state
        budget_s = fo.minutes * 60.0
        rng = np.random.default_rng(fo.seed + 104729 * int(st["segments"]))
        from sim2real.finetune.learner import Learner, RewardShaper

        shaper = RewardShaper(Learner.action_rate_penalty(self.src.config))
        norm = normalizer or (lambda o: np.asarray(o, np.float32))
        objects = env.io.contract.objects
        next_eval = None
        if fo.eval_every_min is not None:
            done_evals = len(st["evals"])
            next_eval = done_evals * fo.eval_every_min * 60.0
        eval_left = 0
        reader = getattr(getattr(env.arm, "link", None), "_thread", None)
        helpers = [reader] if isinstance(reader, threading.Thread) else []
        with (
            control_thread_priority(fo.deploy.realtime, helpers=helpers),
            QuietGC() as quiet,
            single_threaded_blas(),  # the actor's products: no BLAS worker to wait for
        ):
            while True:
                quiet.between()  # the collector runs here, between episodes, not in a period
                used_s = float(st["arm_s"]) - self.start_arm_s
                run_eps = int(st["episodes"]) - self.start_episodes
                over = used_s >= budget_s or (
                    fo.max_episodes is not None and run_eps >= fo.max_episodes
                )
                if (
                    not over
                    and eval_left == 0
                    and next_eval is not None
                    and st["arm_s"] >= next_eval
                ):
                    eval_left = fo.eval_episodes
                    st["evals"].append({"arm_min": st["arm_s"] / 60.0, "successes": 0, "n": 0,
                                        "end_episode": None})  # fmt: skip
                    next_eval += fo.eval_every_min * 60.0  # type: ignore[operator]
                if eval_left == 0 and over:
                    last = st["evals"][-1] if st["evals"] else None
                    if next_eval is None or (last is not None and last["end_episode"] is not None
                                             and last["end_episode"] == st["episodes"]):  # fmt: skip
                        return
                    eval_left = fo.eval_episodes  # a last evaluation of the final actor
                    st["evals"].append({"arm_min": st["arm_s"] / 60.0, "successes": 0, "n": 0,
                                        "end_episode": None})  # fmt: skip
                evaluating = eval_left > 0
                episode = int(st["episodes"])
                t0 = time.monotonic()
                rows = LoopLog()
                truncated = terminated = False
                step = 0
                info: dict[str, Any] = {}
                shaper.reset()
                actor.reset_noise()
                try:
                    # a lost episode's retry draws its objects anew: the placement that made
                    # the policy press the cube into the table would likely do so again
                    retry = RETRY_SEED_STRIDE * self._consecutive_trips
                    obs, _ = env.reset(seed=fo.seed + episode + retry)
                except HardwareError as exc:
                    self._recover(exc, env, t0)
                    continue
                obs_n = norm(obs)
                while not (truncated or terminated):
                    # an evaluation block acts with the actor it began with (its transitions
                    # still teach the learner): the first block is the zero-shot figure, each
                    # later one the actor at that arm minute, not a blend of newer ones
                    weights = None if evaluating else learner.new_weights()
                    if weights is not None:
                        actor.load_flat(weights)
                        self.weight_updates += 1
                    action = actor.act(obs) if evaluating else actor.explore(obs, rng)
                    t_s = time.perf_counter()
                    try:
                        nxt, reward, terminated, truncated, info = env.step(action)
                    except HardwareError as exc:
                        learner.end_episode(False)  # its transitions stay, as a failure
                        self._recover(exc, env, t0)
                        break
                    # the transition as the env saw it: this period's observation, the action
                    # the policy chose (the safety filter acts inside the arm, as in training),
                    # the reward with the source run's training shaping, the next observation
                    nxt_n = norm(nxt)  # the next period's normalised observation too
                    learner.send(obs_n, action, shaper(reward, action), nxt_n, terminated)
                    st["env_steps"] += 1
                    rows.add(
                        t_s=t_s, episode=episode, step=step, obs=obs, action=action,
                        targets_rad=info["targets_rad"], sent_rad=info["sent_rad"],
                        joints_rad=info["joints_rad"], ee_est_m=info["ee_est_m"],
                        ee_seen=math.nan, goal_est_m=info["goal_est_m"],
                        true_tool_m=info["true_tool_m"], period_s=info["period_s"],
                        reward=reward, eval=float(evaluating),
                        **{f"{n}_est_m": info["goal_est_m"] if n == objects[0] else None
                           for n in objects},
                    )  # fmt: skip
                    if recorder is not None:
                        frames = getattr(env.perception, "last_frames", None)
                        recorder.on_period(frames)
                    obs, obs_n = nxt, nxt_n
                    step += 1
                else:
                    self._episode_done(env, learner, human, recorder, rows, info, t0, step,
                                       evaluating)  # fmt: skip
                    self._consecutive_trips = 0
                    if evaluating:
                        eval_left -= 1

    def _recover(self, exc: HardwareError, env: Any, t0: float) -> None:
        """A watchdog trip or an unanswered command on a simulated arm (the machine was too busy
        to feed it, or the mock arm's process to answer), or a stall there (an exploring policy
        pressed the fingers on the table or the cube, and the arm held, then parked itself):
        the episode in flight is lost (ArmEnv parked the arm), the next reset homes it again.
        Anything else, anything on a real arm (a stall there may be a hand in the way: a person
        looks first), or three in a row, stops the run (``--resume`` continues)."""
        if (
            not (isinstance(exc, NoReplyError | StallError) or _tripped(exc))
            or self.fo.deploy.backend == "serial"
            or self._consecutive_trips >= MAX_CONSECUTIVE_TRIPS
        ):
            raise exc
        self._consecutive_trips += 1
        self.watchdog_trips += int(_tripped(exc))
        self.state["arm_s"] = float(self.state["arm_s"]) + time.monotonic() - t0
        self.state["stops"].append(
            {"reason": _why(exc), "episode": self.state["episodes"], "recovered": True,
             "env_steps": self.state["env_steps"]}
        )  # fmt: skip
        log.warning(
            "episode %d lost (%s): homing for the next",
            self.state["episodes"],
            exc,
        )

    def _episode_done(
        self, env: Any, learner: Any, human: Any, recorder: Any, rows: Any, info: dict[str, Any],
        t0: float, step: int, evaluating: bool,
    ) -> None:  # fmt: skip
        fo, st = self.fo, self.state
        episode = int(st["episodes"])
        arm_s = time.monotonic() - t0
        st["arm_s"] = float(st["arm_s"]) + arm_s
        st["episodes"] = episode + 1
        success = bool(info.get("is_success", False))
        learner.end_episode(success)
        rows.save(self.dir.episode_log(episode))
        if recorder is not None:
            recorder.on_episode(episode, success, rows.rows)
        record = {
            "episode": episode,
            "kind": "eval" if evaluating else "train",
            "success": success,
            "judged_on": info.get("judged_on"),
            "distance_m": info.get("distance_m"),
            "steps": step,
            "arm_s": round(arm_s, 3),
            "arm_min_total": round(st["arm_s"] / 60.0, 4),
            "env_steps": st["env_steps"],
        }
        st["episode_log"].append(record)
        if evaluating:
            block = st["evals"][-1]
            block["n"] += 1
            block["successes"] += int(success)
            if block["n"] >= fo.eval_episodes:
                block["end_episode"] = st["episodes"]
        self._interventions(human)
        learner.check()
        if (episode + 1) % fo.checkpoint_every == 0:
            self.checkpoint(learner)
        updates = learner.updates - int(st.get("updates_base", 0))
        self.report({"event": "episode", **record, "learner_updates": updates,
                     "success_last_n": self._recent_success(),
                     **{k: round(v, 3) for k, v in env.timing().items()},
                     "watchdog_trips": self.watchdog_trips, "safety": env.safety_stats})  # fmt: skip

    def _recent_success(self) -> float:
        recent = [e["success"] for e in self.state["episode_log"] if e["kind"] == "train"]
        recent = recent[-self.fo.success_window :]
        return float(np.mean(recent)) if recent else math.nan

    def _interventions(self, human: Any) -> None:
        if human is None:
            return
        seen = {(i["monotonic_s"], i["action"]) for i in self.state["interventions"]}
        for item in human.interventions:
            d = item.to_dict()
            if (d["monotonic_s"], d["action"]) not in seen:
                d["episode"] = self.state["episodes"]
                self.state["interventions"].append(d)

    def summary(self, env: Any, learner: Any) -> FinetuneSummary:
        from sim2real.evaluate.stats import wilson_interval

        periods = np.asarray(env.periods_s)
        jitter = np.abs(periods - env.period_s) * 1e3 if len(periods) else np.zeros(0)
        trips = self.watchdog_trips + sum("watchdog" in e for e in env.estops)
        evals = []
        for block in self.state["evals"]:
            lo, hi = wilson_interval(block["successes"], block["n"])
            rate = block["successes"] / block["n"] if block["n"] else math.nan
            ends = block["end_episode"]
            wilson = (round(lo, 4), round(hi, 4))
            evals.append(
                EvalFigures(block["arm_min"], block["successes"], block["n"], ends, rate, wilson)
            )
        loop = LoopFigures(
            rate_hz=float(1.0 / periods.mean()) if len(periods) else math.nan,
            period_jitter_ms_p50=float(np.percentile(jitter, 50)) if len(jitter) else math.nan,
            period_jitter_ms_p99=float(np.percentile(jitter, 99)) if len(jitter) else math.nan,
            late_periods=env.overruns,
            watchdog_trips=trips,
            recovered_estops=tuple(env.estops),
        )
        return FinetuneSummary(
            out=str(self.fo.out),
            algo=self.algo,
            noise_std=self.noise_std,
            relabel=self.relabel,
            source=self.fo.policy,
            backend=self.fo.deploy.backend,
            plant=self.identity["plant"],
            episodes=self.state["episodes"],
            episodes_this_run=self.state["episodes"] - self.start_episodes,
            env_steps=self.state["env_steps"],
            arm_s=round(float(self.state["arm_s"]), 3),
            success_last_n=self._recent_success(),
            success_window=self.fo.success_window,
            evals=tuple(evals),
            learner_updates=self.state["learner_updates"],
            actor_weight_updates=self.weight_updates,
            loop=loop,
            safety=env.safety_stats,
            arm_end=env.end_state,
            interventions=len(self.state["interventions"]),
            checkpoint=self.state["checkpoint"],
            stopped=self.stop_reason,
        )


def _learner_errors() -> tuple[type[BaseException], ...]:
    from sim2real.finetune.learner import LearnerError

    return (LearnerError,)


def default_anchor(config: dict[str, Any]) -> float:
    """The source run's anchor: ``DAGGER_ANCHOR_RATIO`` where it trained with a DAgger stage."""
    return DAGGER_ANCHOR_RATIO if dict(config.get("train") or {}).get("dagger") else 0.0


def _tripped(exc: BaseException) -> bool:
    """A watchdog's doing: the host's (its e-stop names it) or the firmware's, which switched
    the torque off under a host that stopped talking (the next command is refused for it)."""
    return "watchdog" in str(exc) or isinstance(exc, TorqueOffError)


def _why(exc: BaseException) -> str:
    if isinstance(exc, KeyboardInterrupt):
        from sim2real.errors import Terminated

        return "SIGTERM" if isinstance(exc, Terminated) else "Ctrl-C"
    return f"{type(exc).__name__}: " + (str(exc).splitlines() or [""])[0]


def finetune(
    fo: FinetuneOptions, spec: ArmSpec, report: Report = lambda event: None
) -> FinetuneSummary:
    """Fine-tune ``fo.policy`` on ``fo.deploy``'s arm; the summary (also after an e-stop, a
    start or blind timeout: ``summary.stopped`` says why; ``to_json()`` at the CLI)."""
    return _Run(fo, spec, report).run()
