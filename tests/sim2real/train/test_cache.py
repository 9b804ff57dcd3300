"""``cached_reach_policy``: trained once, then reused; a finished run or nothing is visible."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import sim2real.envs as envs
from sim2real.export import load_policy
from sim2real.train import RunDir, cached_reach_policy
from sim2real.train.cache import _key


def test_second_call_reuses_the_cached_run(tmp_path: Path) -> None:
    first = cached_reach_policy(tmp_path, steps=256)
    stamp = os.stat(first / "model.zip").st_mtime_ns
    again = cached_reach_policy(tmp_path, steps=256)
    assert again == first and os.stat(again / "model.zip").st_mtime_ns == stamp
    assert RunDir(first).read_status()["finished"]
    assert not list(tmp_path.glob(".tmp-*"))  # trained aside, then renamed into place
    assert _key(256, 0, "default") != _key(512, 0, "default")  # another budget, another entry
    assert _key(256, 0, "default") != _key(256, 1, "default")
    policy = load_policy(first)
    obs, _ = envs.make("reach").reset(seed=0)
    assert policy(obs).shape == (3,)


@pytest.mark.slow
def test_default_cached_policy_reaches(tmp_path: Path) -> None:
    from sim2real.evaluate import EvalTarget, evaluate

    run = cached_reach_policy(tmp_path)
    result = evaluate(EvalTarget.load(run), episodes=100)
    assert result["success_rate"] >= 0.5
    assert np.isfinite(result["mean_final_distance_m"])
