"""``sim2real finetune``: fine-tune a sim policy's actor and critic online on the mock or real arm."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from sim2real.cli.verbosity import add_verbose, configure_logging
from sim2real.deploy.connection import add_arm_options, arm_connection


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sim2real.finetune.defaults import ACTOR_UPDATES, LEARNER_DEFAULTS

    parser.add_argument("policy", help="a run directory (DDPG/TD3/SAC) or a shipped policy name")
    add_arm_options(parser, ("mock", "serial"))
    parser.add_argument("--spec", default=None, help="ArmSpec YAML (default: the shipped arm)")
    parser.add_argument(
        "--minutes", type=float, default=15.0, help="arm minutes to learn for (this run)"
    )
    parser.add_argument(
        "--algo", default=None, help="ddpg | td3 | sac (default: the source's; td3 may continue "
        "a ddpg checkpoint)"
    )  # fmt: skip
    parser.add_argument(
        "--mix-sim-buffer", action="store_true",
        help="sample every batch 50/50 from online and sim transitions (RLPD)",
    )  # fmt: skip
    parser.add_argument("--sim-buffer-steps", type=int, default=5000)
    parser.add_argument("--resume", action="store_true", help="continue the fine-tune in --out")
    parser.add_argument(
        "--out", type=Path, default=None, help="run dir (default: runs/finetune-<policy>)"
    )
    parser.add_argument(
        "--keys", action=argparse.BooleanOptionalAction, default=None,
        help="human-in-the-loop keys on the terminal (default: when stdin is a terminal)",
    )  # fmt: skip
    parser.add_argument("--checkpoint-every", type=int, default=1, help="episodes")
    parser.add_argument(
        "--learning-starts", type=int, default=LEARNER_DEFAULTS["learning_starts"],
        help="online steps before the first gradient step",
    )  # fmt: skip
    parser.add_argument(
        "--utd", type=float, default=LEARNER_DEFAULTS["utd"], help="gradient steps per env step"
    )
    parser.add_argument(
        "--actor-starts", type=int, default=LEARNER_DEFAULTS["actor_starts"],
        help="online steps of critic-only updates before the actor learns",
    )  # fmt: skip
    parser.add_argument(
        "--learning-rate", type=float, default=None, help="actor and critic (default: the source's)"
    )
    parser.add_argument(
        "--noise-std", type=float, default=None,
        help="DDPG/TD3 exploration noise std on the normalised actions "
        f"(default: {LEARNER_DEFAULTS['noise_std']})",
    )  # fmt: skip
    parser.add_argument(
        "--noise-corr-steps", type=float, default=0.0,
        help="exploration noise correlated over about this many steps (AR(1)); 0: white",
    )  # fmt: skip
    parser.add_argument(
        "--gripper-noise-std", type=float, default=None,
        help="the gripper's own exploration std (default: --noise-std): a policy that never "
        "closes where the arm stalls needs to try closing there",
    )  # fmt: skip
    parser.add_argument(
        "--relabel", type=float, default=None,
        help="share of every batch given a goal the tool reached later in its episode (hindsight "
        f"relabelling; default: {LEARNER_DEFAULTS['relabel']} for reach, 0 for tasks without goals)",
    )  # fmt: skip
    parser.add_argument(
        "--anchor", type=float, default=None,
        help="imitation minibatches towards the source actor per gradient step (default: 0.5 for "
        "a source trained with a DAgger stage, such as pick-ddpg; 0 otherwise)",
    )  # fmt: skip
    parser.add_argument(
        "--actor-update", choices=sorted(ACTOR_UPDATES), default="critic",
        help="how the actor learns: 'critic' follows the critic's gradient (DDPG/TD3's own "
        "update); 'success' imitates the arm's own successful episodes; 'advantage' imitates "
        "every action taken, weighted by the critic's advantage (AWAC); the critic learns in all",
    )  # fmt: skip
    parser.add_argument(
        "--imitation-ratio", type=float, default=1.0,
        help="with --actor-update success or advantage: imitation minibatches per gradient step",
    )  # fmt: skip
    parser.add_argument("--publish-every", type=int, default=20, help="env steps per weight push")
    parser.add_argument("--batch-size", type=int, default=None)
    parser.add_argument("--learner-nice", type=int, default=10)
    parser.add_argument("--success-window", type=int, default=20)
    parser.add_argument("--eval-every", type=float, default=None, help="arm minutes between evals")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--max-episodes", type=int, default=None, help="cap for this run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--start-timeout", type=float, default=10.0)
    parser.add_argument(
        "--record-dataset", type=Path, default=None, metavar="DIR",
        help="also write the episodes as a LeRobot dataset",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="JSON lines: each episode, a summary")
    add_verbose(parser)


def run(args: argparse.Namespace) -> int:
    from hardware.spec import load_spec
    from sim2real.finetune.runner import FinetuneOptions, finetune

    configure_logging(args)
    opts = arm_connection(args)
    spec = load_spec(args.spec)
    out = args.out or Path("runs") / f"finetune-{Path(args.policy).name}"
    fo = FinetuneOptions(
        policy=args.policy, out=out, deploy=opts, minutes=args.minutes, algo=args.algo,
        mix_sim_buffer=args.mix_sim_buffer, sim_buffer_steps=args.sim_buffer_steps,
        resume=args.resume, keys=args.keys, checkpoint_every=args.checkpoint_every,
        learning_starts=args.learning_starts, utd=args.utd, actor_starts=args.actor_starts,
        learning_rate=args.learning_rate, noise_std=args.noise_std, relabel=args.relabel,
        noise_corr_steps=args.noise_corr_steps, gripper_noise_std=args.gripper_noise_std,
        anchor=args.anchor, actor_update=args.actor_update, imitation_ratio=args.imitation_ratio,
        publish_every=args.publish_every,
        batch_size=args.batch_size, learner_nice=args.learner_nice,
        success_window=args.success_window, eval_every_min=args.eval_every,
        eval_episodes=args.eval_episodes, max_episodes=args.max_episodes, seed=args.seed,
        start_timeout_s=args.start_timeout, record_dataset=args.record_dataset,
    )  # fmt: skip

    def report(event: dict[str, Any]) -> None:
        if args.json:
            print(json.dumps(event, default=_plain), flush=True)
        elif event.get("event") == "episode":
            print(
                f"episode {event['episode']:4d} {event['kind']:5s} "
                f"success={int(event['success'])} arm {event['arm_min_total']:6.2f} min "
                f"steps {event['env_steps']} updates {event['learner_updates']} "
                f"recent {event['success_last_n']:.2f}",
                flush=True,
            )

    summary = finetune(fo, spec, report)
    body = summary.to_json()  # JSON only here, at the edge
    if args.json:
        print(json.dumps(body, default=_plain), flush=True)
    else:
        for key, value in body.items():
            if key != "event":
                print(f"{key:22s} {value}")
    return 0 if summary.stopped is None else 1


def _plain(value: Any) -> Any:
    import numpy as np

    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)
