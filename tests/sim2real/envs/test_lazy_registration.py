"""``import sim2real`` registers every id, and stays cheap: checked in a fresh interpreter."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("mujoco", "torch", "robosuite", "numba")

_PROBE = """
import json, sys
import sim2real
import gymnasium as gym
import sim2real.envs as envs
heavy = [m for m in {heavy!r} if m in sys.modules]
ids = sorted(k for k in gym.registry if k.startswith("Sim2Real/"))
env = gym.make({make_id!r})
obs, _ = env.reset(seed=0)
env.close()
print(json.dumps({{"heavy_after_import": heavy, "ids": ids, "table": sorted(envs.env_ids()),
                  "obs_len": len(obs), "space_len": env.observation_space.shape[0],
                  "mujoco_after_make": "mujoco" in sys.modules}}))
"""


def _probe(make_id: str) -> dict[str, object]:
    code = _PROBE.format(heavy=HEAVY, make_id=make_id)
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True
    )
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def test_import_sim2real_registers_every_id_without_heavy_imports() -> None:
    got = _probe("Sim2Real/Arm3Reach-v0")
    assert got["heavy_after_import"] == []
    assert got["ids"] == got["table"] and len(got["ids"]) >= 8  # type: ignore[arg-type]
    assert got["obs_len"] == got["space_len"] > 0  # a real reach env was made and reset
    assert got["mujoco_after_make"] is True


def test_module_prefixed_id_still_works() -> None:
    """``gym.make("sim2real:Sim2Real/...")`` imports the package named before the colon."""
    got = _probe("sim2real:Sim2Real/Arm3Pick-v0")
    assert got["heavy_after_import"] == []
    assert got["mujoco_after_make"] is True
