"""How the ids are registered: ``max_episode_steps`` reaches the env, action-space flags agree."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import sim2real.envs as envs


def _episode(env: gym.Env[Any, Any], action: Any) -> tuple[int, bool, bool]:
    """Steps until the episode ends: (length, terminated, truncated) of its last step."""
    env.reset(seed=0)
    for n in range(1, 1000):
        _, _, term, trunc, _ = env.step(action)
        if term or trunc:
            return n, term, trunc
    raise AssertionError("episode did not end")


@pytest.mark.parametrize("steps", [7, 80])
def test_gym_make_max_episode_steps_is_the_envs_own_length(steps: int) -> None:
    env = gym.make("Sim2Real/Arm3Reach-v0", max_episode_steps=steps)
    assert env.unwrapped.max_episode_steps == steps  # type: ignore[attr-defined]
    assert _episode(env, np.zeros(3, np.float32)) == (steps, False, True)
    again = gym.make(env.spec)  # type: ignore[arg-type]
    assert again.unwrapped.max_episode_steps == steps  # type: ignore[attr-defined]
    env.close()
    again.close()


def test_default_length_without_a_time_limit() -> None:
    env = gym.make("Sim2Real/Arm3Reach-v0")
    assert env.spec is not None and env.spec.max_episode_steps is None
    assert _episode(env, np.zeros(3, np.float32)) == (50, False, True)
    env.close()


def test_a_short_kuka_episode_still_closes_and_lifts() -> None:
    """Its end-of-episode grasp runs at the env's own length, not at a TimeLimit cut."""
    env = gym.make("Sim2Real/KukaGraspFastCont-v0", max_episode_steps=4)
    length, terminated, _ = _episode(env, np.zeros(3, np.float32))
    assert (length, terminated) == (4, True)  # a TimeLimit cut alone would not terminate
    env.close()


@pytest.mark.parametrize("name", ["kuka-fast", "kuka-fast-cont", "reach", "pick-pixels"])
def test_discrete_action_flag_matches_the_built_env(name: str) -> None:
    env = envs.make(name)
    assert envs.has_discrete_actions(name) == isinstance(env.action_space, gym.spaces.Discrete)
    env.close()


@pytest.mark.parametrize("env_id", ["Sim2Real/Arm3Pick-v0", "Sim2Real/Arm3ReachGoal-v0"])
def test_arm_envs_enforce_reset_before_step_without_the_wrapper(env_id: str) -> None:
    """The arm ids are made without Gymnasium's OrderEnforcing (one layer less per step): the
    env itself refuses step and render before the first reset, as the wrapper did."""
    env = gym.make(env_id, render_mode="rgb_array")
    assert env is env.unwrapped  # no wrapper between the user and the env
    with pytest.raises(gym.error.ResetNeeded):
        env.step(env.action_space.sample())
    with pytest.raises(gym.error.ResetNeeded):
        env.render()
    env.reset(seed=0)
    env.step(env.action_space.sample())
    env.close()
