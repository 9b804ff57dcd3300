"""``--placements held-out``: a deploy replays the objects of ``evaluate``'s held-out episodes."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs  # noqa: F401
from sim2real.cli.main import main
from sim2real.deploy.replayed import placements
from sim2real.errors import UnknownNameError
from sim2real.train.config import EVAL_SEED_BASE


def test_a_sim_deploy_places_the_cubes_of_the_held_out_episodes(tmp_path: Path) -> None:
    log = tmp_path / "held_out.npz"
    args = ["deploy", "pick-ppo", "--backend", "sim", "--sim-clock", "lockstep",
            "--episodes", "2", "--steps", "2",
            "--placements", "held-out", "--log", str(log), "--json"]  # fmt: skip
    assert main(args) == 0
    rows = np.load(log)
    # evaluate's first two held-out episodes, rebuilt independently: the env reset by seed
    env = gym.make("Sim2Real/Arm3Pick-v0", dr="none")
    for i in range(2):
        env.reset(seed=EVAL_SEED_BASE + i)
        cube_m = env.unwrapped.task.cube_position(env.unwrapped)
        first = int(np.flatnonzero(rows["episode"] == i)[0])
        np.testing.assert_allclose(rows["cube_true_m"][first][:2], cube_m[:2], atol=1e-6)
    env.close()


def test_the_loop_source_leaves_the_draws_to_the_loop() -> None:
    assert placements("loop", "pick-ppo", 5) == ()
    held = placements("held-out", "pick-ppo", 3)
    assert len(held) == 3 and all(set(p) == {"cube"} for p in held)


def test_an_unknown_source_names_the_valid_ones() -> None:
    with pytest.raises(UnknownNameError, match="'random'.*held-out, loop"):
        placements("random", "pick-ppo", 1)


def test_a_real_arm_refuses_replayed_placements(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["deploy", "pick-ppo", "--backend", "serial", "--port", "/dev/null",
            "--placements", "held-out"]  # fmt: skip
    assert main(args) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--placements held-out" in err, err


def test_replayed_trace_seams_are_the_held_out_ones_the_rig_can_see() -> None:
    """Some env seams end under the arm's base: replayed, such an episode would never start.
    The held-out source skips them, as the loop's own draws do, and says which seeds it kept."""
    from sim2real.deploy.placement import RigSight
    from sim2real.deploy.replayed import held_out_in_view
    from sim2real.envs.trace import TraceContract
    from sim2real.evaluate.core import EvalTarget, held_out_placements
    from sim2real.model import RigSpec
    from sim2real.policies import resolve_policy

    target = EvalTarget.load(resolve_policy("trace-ppo"))
    seeds, kept = held_out_in_view(target, 5)
    looked = seeds[-1] - target.held_out_seeds(1)[0] + 1  # held-out episodes looked at
    first = target.held_out_seeds(looked)
    assert len(seeds) == len(kept) == 5 and looked > 5  # some of the first five were skipped
    assert seeds == sorted(seeds) and set(seeds) <= set(first)
    skipped = sorted(set(first) - set(seeds))
    every = held_out_placements(target, looked)
    sight = RigSight(target.spec, "trace", TraceContract.objects, RigSpec())
    try:
        for seed, placement in zip(seeds, kept, strict=True):
            np.testing.assert_allclose(placement["seam"], every[first.index(seed)]["seam"])
            assert sight.unseen(placement) is None
        assert all(sight.unseen(every[first.index(s)]) is not None for s in skipped)
    finally:
        sight.close()
