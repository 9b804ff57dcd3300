"""``--perception fk`` and the deploy path without the simulator: the tool is the spec's forward
kinematics of the readings, the objects are where the episode placed them, and a policy's
builder, decoder and contract come out the same with MuJoCo and Gymnasium hidden as with them.
(The deploy itself, in a venv with the deploy extra only, is in ``tests/test_install_profiles``.)
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hardware.arm import ArmState
from hardware.spec import ArmSpec
from sim2real import env_table
from sim2real.deploy.kinematic import KinematicPerception, KinematicWorld
from sim2real.deploy.policy_io import policy_io
from sim2real.deploy.runner import DeployOptions
from sim2real.envs.reach_contract import ReachContract
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.export import load_policy
from sim2real.policies import shipped


def test_fk_perception_reports_the_kinematics_of_the_readings_and_the_placed_objects(
    spec: ArmSpec,
) -> None:
    world = KinematicWorld()
    perception = KinematicPerception(spec, world)
    contract = ReachContract(spec, 20.0, 50)
    placement = contract.placement(np.random.default_rng(3))
    world.new_episode({**placement, "cube": np.array([0.2, 0.0, 0.0125, 0.7])})  # pose + yaw
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(spec.lower_rad, spec.upper_rad)
        percept = perception.perceive(ArmState(q, 0.0), 0.0)
        assert percept.tool_m is not None
        np.testing.assert_array_equal(percept.tool_m, spec.forward_kinematics(q[: spec.n_joints]))
        np.testing.assert_array_equal(percept.position("target"), placement["target"])
        np.testing.assert_array_equal(percept.position("cube"), [0.2, 0.0, 0.0125])
        assert percept.blind_s("target") == 0.0
    assert contract.ready(percept, 0.0) is not None  # still waits for a still window, as a real arm
    assert world.view(np.zeros(3), None) is None  # no truth: judged on the estimates
    assert not world.places_objects  # never re-placed: a person sets them


def test_fk_perception_is_an_option_of_the_serial_backend_only() -> None:
    DeployOptions(backend="serial", port="/dev/null", perception="fk")
    with pytest.raises(UnknownNameError, match="unknown perception 'lidar'; valid: cameras, fk"):
        DeployOptions(backend="serial", port="/dev/null", perception="lidar")
    with pytest.raises(ConfigError, match="--perception is for --backend serial, not 'mock'"):
        DeployOptions(backend="mock", perception="fk")


def test_the_contract_table_names_each_task_s_own_contract() -> None:
    import sim2real.envs as envs

    arm_tasks = {n for n, t in envs.TASKS.items() if t.contract is not None}
    assert set(env_table.DEPLOY_CONTRACTS) == arm_tasks
    for name in arm_tasks:
        module, _, cls = env_table.DEPLOY_CONTRACTS[name].partition(":")
        assert getattr(__import__(module, fromlist=[cls]), cls) is envs.TASKS[name].contract


# A child with MuJoCo and Gymnasium unimportable (any import of them fails), as in the deploy
# profile: it prints the builder's layout, the decoder's size and the contract of a policy.
_NO_SIM = """
import json, sys
for m in ("mujoco", "gymnasium", "torch", "stable_baselines3"):
    sys.modules[m] = None
from hardware.spec import load_spec
from sim2real.deploy.policy_io import policy_io
from sim2real.errors import ConfigError
from sim2real.export import load_policy
out = {}
for name in sys.argv[1:]:
    try:
        io = policy_io(load_spec(), load_policy(name).meta)
    except ConfigError as exc:
        out[name] = str(exc)
        continue
    out[name] = [[[f.name, f.start, f.stop] for f in io.builder.layout()],
                 io.decoder.n_actions, io.contract.__name__, io.episode_steps, io.task]
print(json.dumps(out))
"""


def test_a_shipped_policy_s_io_is_the_same_without_the_simulator(spec: ArmSpec) -> None:
    names = sorted(  # the arm's state policies: a camera policy is refused (test_shipped)
        n
        for n, s in shipped().items()
        if s.task in env_table.DEPLOY_CONTRACTS and load_policy(n).meta.obs_mode != "pixels"
    )
    assert "reach-ppo" in names
    proc = subprocess.run(
        [sys.executable, "-c", _NO_SIM, *names], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    lean = json.loads(proc.stdout)
    for name in names:
        io = policy_io(spec, load_policy(name).meta)  # with the simulator: from the task class
        if io.task == "reach":  # reach's contract imports no MuJoCo: it deploys lean
            assert lean[name] == [
                [[f.name, f.start, f.stop] for f in io.builder.layout()],
                io.decoder.n_actions, io.contract.__name__, io.episode_steps, io.task,
            ], name  # fmt: skip
        else:  # the others name the extra they need, in one line
            assert "pip install 'sim2real[sim]'" in lean[name] and "\n" not in lean[name]
