"""Is the source critic calibrated on the plant? Its Q(s, a) against the discounted returns that
the exploring source actor actually collects, in sim (the training DR) and on the plant proxy.

A critic that overestimates the plant's returns steers a DDPG/TD3 actor with a wrong gradient
until it has refit them; this prints how far off it starts. Returns are the shaped rewards the
learner trains on (``RewardShaper``), discounted with the source's gamma over each episode's
first ``--horizon`` steps (the rest of the episode bootstraps nothing: a truncated Monte-Carlo
return, so even sim shows a positive bias of the tail's size).

    nice -n 10 .venv/bin/python bench/finetune_critic.py reach-ddpg --plant hard
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
from support.load import emit_row

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    import torch as th
    from finetune_proxy import plant_env  # type: ignore[import-not-found]

    import sim2real.envs as envs
    from sim2real.finetune.actor import NumpyActor, ObsNormalizer
    from sim2real.finetune.checkpoint import resolve
    from sim2real.finetune.learner import Learner, LearnerConfig, RewardShaper

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy", nargs="?", default="reach-ddpg")
    p.add_argument("--plant", default="hard")
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--horizon", type=int, default=20)
    a = p.parse_args()

    src = resolve(a.policy, None)
    pen = Learner.action_rate_penalty(src.config)
    learner = Learner(
        LearnerConfig(algo=src.algo, source_algo=src.algo, model_zip=str(src.model_zip),
                      obs_stats=src.obs_stats, action_rate_penalty=pen)
    )  # fmt: skip
    gamma = float(learner.model.gamma)
    nz = ObsNormalizer.from_stats(src.obs_stats)
    norm = nz or (lambda o: np.asarray(o, np.float32))
    actor = NumpyActor(learner.kind, learner.shapes, learner.flat_actor(), nz, learner.noise_std)
    env_id, kw = str(src.config["env_id"]), dict(src.config.get("env_kwargs", {}))
    hz = float(src.config.get("control_hz", 20.0))
    for name, env in (
        ("sim", envs.make(env_id, **kw)),
        ("plant", plant_env(env_id, kw, a.plant, hz)),
    ):
        rng = np.random.default_rng(0)
        obs_l: list[np.ndarray] = []
        act_l: list[np.ndarray] = []
        ret_l: list[float] = []
        rewards: list[float] = []
        wins, final_m = 0, []
        for ep in range(a.episodes):
            obs, _ = env.reset(seed=ep)
            shaper = RewardShaper(pen)
            rs: list[float] = []
            info: dict[str, Any] = {}
            done = False
            while not done:
                act = actor.explore(obs, rng)
                nxt, r, term, trunc, info = env.step(act)
                rs.append(shaper(float(r), act))
                obs_l.append(norm(obs))
                act_l.append(act)
                obs, done = nxt, term or trunc
            wins += int(bool(info.get("is_success", False)))
            final_m.append(float(info["distance_m"]))
            g, returns = 0.0, []
            for r in reversed(rs):
                g = r + gamma * g
                returns.append(g)
            returns.reverse()
            keep = min(a.horizon, len(rs))
            del obs_l[len(obs_l) - len(rs) + keep :], act_l[len(act_l) - len(rs) + keep :]
            ret_l += returns[:keep]
            rewards += rs
        with th.no_grad():
            q = learner.model.critic(th.as_tensor(np.stack(obs_l)), th.as_tensor(np.stack(act_l)))
        qv, mc = q[0].numpy().ravel(), np.asarray(ret_l)
        emit_row({
            "metric": "finetune_critic_bias", "value": round(float((qv - mc).mean()), 3),
            "unit": "return", "world": name, "plant": a.plant if name == "plant" else None,
            "q_mean": round(float(qv.mean()), 3), "mc_mean": round(float(mc.mean()), 3),
            "rmse": round(float(np.sqrt(((qv - mc) ** 2).mean())), 3),
            "corr": round(float(np.corrcoef(qv, mc)[0, 1]), 3),
            "success_exploring": wins / a.episodes,
            "final_distance_mm": round(1e3 * float(np.mean(final_m)), 2),
            "reward_per_step": round(float(np.mean(rewards)), 4), "episodes": a.episodes,
        })  # fmt: skip
        env.close()


if __name__ == "__main__":
    main()
