"""A policy's observation builder, action decoder and deploy contract, from (spec, metadata).

Deploy must not build a MuJoCo env to borrow them: the env id names a task and an observation
mode in the env table (``sim2real.env_table``; no env is made), the task lists its observation
fields (or, without the simulator, the policy's record does), and the metadata carries the action
scaling the policy was trained with. The layout rebuilt here is
checked against the layout the policy recorded, field by field.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from hardware.spec import ArmSpec
from sim2real import env_table
from sim2real.envs.contract import DeployContract
from sim2real.errors import ConfigError, UnknownNameError
from sim2real.observation import ActionDecoder, ObservationBuilder, ObsField
from sim2real.runmeta import RunMeta

# What the deploy profile lacks: a module missing for one of these means "no simulator here".
SIM_MODULES = frozenset({"mujoco", "gymnasium"})


@dataclass(frozen=True)
class PolicyIO:
    task: str
    builder: ObservationBuilder
    decoder: ActionDecoder
    contract: type[DeployContract]
    episode_steps: int

    def new_contract(self, spec: ArmSpec, control_hz: float) -> DeployContract:
        return self.contract(spec, control_hz, self.episode_steps)


def io_for(
    spec: ArmSpec,
    env_id: str,
    max_delta_rad: float = 0.1,
    env_kwargs: dict[str, object] | None = None,
    source: str = "",
    recorded: RunMeta | None = None,
) -> PolicyIO:
    """The builder, decoder and contract of a registered env id, without building the env.

    The task's observation fields come from its ``Task`` class where the simulator is installed;
    in the deploy profile (no MuJoCo) from the layout the policy ``recorded``, field by field,
    which is what the task built when the policy was trained."""
    try:
        entry = env_table.entry(env_id)
    except UnknownNameError:
        raise ConfigError(
            f"policy {source!r} was trained on {env_id!r}, which this version does not "
            "register (sim2real envs lists the ids)"
        ) from None
    kwargs = {**entry.kwargs, **dict(env_kwargs or {})}
    task_name = str(kwargs.get("task", ""))
    contract = _contract(task_name, source, env_id)
    obs_mode = str(kwargs.get("obs_mode", "state"))
    if obs_mode == "pixels":
        raise ConfigError(f"policy {source!r} observes pixels ({env_id}); deploy feeds state")
    steps = int(str(kwargs.get("max_episode_steps", 50)))
    task_cls = _task_class(task_name)
    if task_cls is not None:
        decoder = ActionDecoder(spec, max_delta_rad, use_gripper=task_cls.uses_gripper)
        n_readings = spec.n_joints + (1 if task_cls.uses_gripper else 0)
        fields = task_cls().obs_fields(n_readings, decoder.n_actions, obs_mode == "goal")
    elif recorded is not None and recorded.obs_layout:
        gripper = recorded.action_dim == spec.n_joints + 1
        decoder = ActionDecoder(spec, max_delta_rad, use_gripper=gripper)
        fields = tuple(ObsField(f.name, f.size, f.unit, f.doc) for f in recorded.obs_layout)
    else:
        raise ConfigError(
            f"the observation layout of {env_id} comes from its task, which needs the simulator: "
            "pip install 'sim2real[sim]' (or deploy an exported policy, which records it)"
        )
    return PolicyIO(task_name, ObservationBuilder(fields), decoder, contract, steps)


def _contract(task: str, source: str, env_id: str) -> type[DeployContract]:
    ref = env_table.DEPLOY_CONTRACTS.get(task)
    if ref is None:
        raise ConfigError(
            f"policy {source!r} ({env_id}) has no deploy contract: deploy runs the arm tasks "
            f"{sorted(env_table.DEPLOY_CONTRACTS)}"
        )
    module, _, name = ref.partition(":")
    try:
        cls: type[DeployContract] = getattr(importlib.import_module(module), name)
    except ModuleNotFoundError as exc:
        if exc.name not in SIM_MODULES:
            raise
        raise ConfigError(
            f"deploying a {task} policy needs the simulator's scene names ({exc.name} is "
            "missing): pip install 'sim2real[sim]'"
        ) from None
    return cls


def _task_class(task: str) -> Any:
    """The registered ``Task`` class, or None where the simulator is not installed."""
    try:
        import sim2real.envs as envs

        return envs.TASKS.get(task)
    except ModuleNotFoundError as exc:
        if exc.name not in SIM_MODULES:
            raise
        return None


def policy_io(spec: ArmSpec, meta: RunMeta) -> PolicyIO:
    """Pure: the same inputs always give the same builder and decoder; no env is built. The
    layout is checked against the one the policy recorded."""
    env_kwargs = dict(meta.env_kwargs)
    io = io_for(spec, meta.env_id, meta.max_delta_rad, env_kwargs, meta.source, recorded=meta)
    meta.check_layout([(f.name, f.stop - f.start) for f in io.builder.layout()])
    if meta.obs_keys is None and io.builder.size != meta.flat_obs_dim:
        raise ConfigError(
            f"policy expects {meta.flat_obs_dim} observations, the {meta.env_id} layout has "
            f"{io.builder.size}"
        )
    if meta.action_dim and meta.action_dim != io.decoder.n_actions:
        raise ConfigError(
            f"policy outputs {meta.action_dim} actions, task {io.task!r} on this arm takes "
            f"{io.decoder.n_actions}"
        )
    return io
