"""A faster-than-real-time proxy of ``sim2real finetune`` on a plant: the learner's own code
(``finetune.learner.Learner``, the loop's ``NumpyActor``, the runner's transition and reward
rules) stepping the policy's training env with the plant's defects forced into every episode.

Real-time mock runs cost 15 wall minutes each and the machine's load distorts them; this proxy
answers "does this learner setting improve within ~18,000 env steps (15 arm minutes at 20 Hz)?"
in a few wall minutes, so settings can be compared. It is a proxy, not the mock arm: the plant is
approximated in the env's DR terms (link deltas and joint offsets from the plant file, the pitch
joints' droop as an offset, the extra command latency as whole control steps, the servo speed as
a scale); figures that matter are confirmed on the mock arm (``bench/finetune_mock.py``).

JSON lines: one per evaluation (deterministic actor, the same ``--eval-episodes`` goals each time)
with the env steps, the gradient steps and the learner's wall seconds so far.

    nice -n 10 .venv/bin/python bench/finetune_proxy.py reach-ddpg --plant hard --steps 18000
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
from support.load import emit_row


def emit(metric: str, value: object, unit: str = "", **extra: object) -> None:
    emit_row({"metric": metric, "value": value, "unit": unit, **extra})


def plant_env(env_id: str, env_kwargs: dict[str, Any], plant_name: str, control_hz: float) -> Any:
    """The training env whose every episode is the plant (its DR draws overridden)."""
    import sim2real.envs as envs
    from hardware.plant import load_plant
    from hardware.spec import load_spec

    nominal = load_spec(None)
    plant = load_plant(plant_name)
    links = [
        plant.spec.links.base_height_m - nominal.links.base_height_m,
        plant.spec.links.upper_arm_m - nominal.links.upper_arm_m,
        plant.spec.links.forearm_m - nominal.links.forearm_m,
    ]
    offsets = np.asarray(plant.offsets_rad()[:3], dtype=float)
    offsets[1:] -= plant.droop_rad  # the pitch joints sag: an offset toward gravity
    extra_steps = round(plant.command_latency_s * control_hz)
    speed_scale = plant.spec.servo.max_speed_rad_s / nominal.servo.max_speed_rad_s
    env = envs.make(env_id, **env_kwargs)
    rz = env.unwrapped.randomizer
    draw = rz.sample

    def sample(rng: np.random.Generator) -> Any:
        params = draw(rng)
        params["kinematics"]["link_length_delta_m"] = np.asarray(links)
        params["kinematics"]["joint_offset_rad"] = offsets.copy()
        params["kinematics"]["tool_offset_delta_m"] = np.zeros(2)
        act = params["actuation"]
        act["latency_steps"] = int(act["latency_steps"]) + extra_steps
        act["max_speed_scale"] = speed_scale
        act["deadband_rad"] = plant.spec.servo.deadband_rad
        return params

    rz.sample = sample
    return env


def evaluate(env: Any, actor: Any, episodes: int, seed: int) -> float:
    wins = 0
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i)
        done = False
        info: dict[str, Any] = {}
        while not done:
            obs, _, term, trunc, info = env.step(actor.act(obs))
            done = term or trunc
        wins += int(bool(info.get("is_success", False)))
    return wins / episodes


def main() -> None:
    from sim2real.finetune.actor import NumpyActor, ObsNormalizer
    from sim2real.finetune.checkpoint import resolve
    from sim2real.finetune.defaults import ACTOR_UPDATES, LEARNER_DEFAULTS
    from sim2real.finetune.learner import Learner, LearnerConfig, RewardShaper, SimBufferConfig
    from sim2real.finetune.relabel import default_ratio, goal_fields
    from sim2real.finetune.runner import default_anchor

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy")
    p.add_argument("--plant", default="hard")
    p.add_argument("--algo", default=None)
    p.add_argument("--steps", type=int, default=18000)
    p.add_argument("--eval-every", type=int, default=3000)
    p.add_argument("--eval-episodes", type=int, default=30)
    p.add_argument("--utd", type=float, default=LEARNER_DEFAULTS["utd"])
    p.add_argument("--learning-starts", type=int, default=LEARNER_DEFAULTS["learning_starts"])
    p.add_argument("--actor-delay", type=int, default=LEARNER_DEFAULTS["actor_starts"])
    p.add_argument("--publish-every", type=int, default=20)
    p.add_argument("--noise", type=float, default=None, help="exploration std")
    p.add_argument("--lr", type=float, default=None)
    p.add_argument("--no-penalty", action="store_true", help="drop the action-rate penalty")
    p.add_argument("--mix-sim-buffer", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--relabel", type=float, default=None, help="default: finetune's for the task")
    p.add_argument("--anchor", type=float, default=None, help="default: finetune's for the source")
    p.add_argument("--actor-update", choices=sorted(ACTOR_UPDATES), default="critic")
    p.add_argument("--imitation-ratio", type=float, default=1.0)
    p.add_argument("--noise-corr-steps", type=float, default=0.0, help="AR(1) exploration noise")
    p.add_argument("--gripper-noise", type=float, default=None, help="the gripper's own std")
    a = p.parse_args()

    src = resolve(a.policy, a.algo)
    algo = a.algo or src.algo
    hz = float(src.config.get("control_hz", 20.0))
    env_kwargs = dict(src.config.get("env_kwargs", {}))
    env = plant_env(str(src.config["env_id"]), env_kwargs, a.plant, hz)
    eval_env = plant_env(str(src.config["env_id"]), env_kwargs, a.plant, hz)
    sim = None
    if a.mix_sim_buffer:
        from hardware.spec import load_spec

        sim = SimBufferConfig(str(src.config["env_id"]), env_kwargs, load_spec(None),
                              seed=a.seed)  # fmt: skip
    penalty = 0.0 if a.no_penalty else Learner.action_rate_penalty(src.config)
    relabel = default_ratio(src.config) if a.relabel is None else a.relabel
    anchor = default_anchor(src.config) if a.anchor is None else a.anchor
    cfg = LearnerConfig(
        algo=algo, source_algo=src.algo, model_zip=str(src.model_zip), obs_stats=src.obs_stats,
        learning_starts=a.learning_starts, utd=a.utd, seed=a.seed, sim_buffer=sim,
        actor_starts=a.actor_delay, learning_rate=a.lr,
        action_rate_penalty=penalty, relabel_ratio=relabel,
        goal_fields=goal_fields(src.config) if relabel > 0 else None,
        anchor_ratio=anchor, anchor_zip=str(src.model_zip) if anchor > 0 else None,
        actor_update=a.actor_update, imitation_ratio=a.imitation_ratio,
    )  # fmt: skip
    t0 = time.monotonic()
    learner = Learner(cfg)
    shaper = RewardShaper(penalty)
    normalizer = ObsNormalizer.from_stats(src.obs_stats)
    norm = normalizer or (lambda o: np.asarray(o, np.float32))
    actor = NumpyActor(learner.kind, learner.shapes, learner.flat_actor(), normalizer,
                       a.noise if a.noise is not None else LEARNER_DEFAULTS["noise_std"],
                       a.noise_corr_steps, a.gripper_noise)  # fmt: skip
    rng = np.random.default_rng(a.seed)
    setting = {k: v for k, v in vars(a).items() if k not in ("policy",)}
    learn_s = 0.0
    emit("proxy_eval_success", evaluate(eval_env, actor, a.eval_episodes, 10_000), "",
         env_steps=0, updates=0, **setting)  # fmt: skip
    obs, _ = env.reset(seed=a.seed)
    shaper.reset()
    pending = 0.0
    for step in range(1, a.steps + 1):
        action = actor.explore(obs, rng)
        nxt, reward, term, trunc, info = env.step(action)
        learner.add(norm(obs), action, shaper(reward, action), norm(nxt), term)
        obs = nxt
        if term or trunc:
            learner.end_episode(bool(info.get("is_success", False)))
            actor.reset_noise()
            obs, _ = env.reset()
            shaper.reset()
        if learner.buffer.size() >= a.learning_starts:
            pending += a.utd
            if pending >= 1:
                t1 = time.monotonic()
                learner.train(int(pending))
                learn_s += time.monotonic() - t1
                pending -= int(pending)
        if step % a.publish_every == 0:
            actor.load_flat(learner.flat_actor())
        if step % a.eval_every == 0:
            actor.load_flat(learner.flat_actor())
            emit("proxy_eval_success", evaluate(eval_env, actor, a.eval_episodes, 10_000), "",
                 env_steps=step, updates=learner.updates - learner.start_updates,
                 successful_transitions=learner.successful_transitions,
                 learn_s=round(learn_s, 1), wall_s=round(time.monotonic() - t0, 1),
                 **setting)  # fmt: skip


if __name__ == "__main__":
    main()
