"""A policy's observation builder, action decoder and deploy contract, from (spec, metadata).

Deploy must not build a MuJoCo env to borrow them: the env id names a task and an observation
mode in Gymnasium's registry (no env is made), the task lists its observation fields, and the
metadata carries the action scaling the policy was trained with. The layout rebuilt here is
checked against the layout the policy recorded, field by field.
"""

from __future__ import annotations

from dataclasses import dataclass

from hardware.spec import ArmSpec
from sim2real.envs.contract import DeployContract
from sim2real.errors import ConfigError
from sim2real.export.policy import PolicyMeta
from sim2real.observation import ActionDecoder, ObservationBuilder


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
) -> PolicyIO:
    """The builder, decoder and contract of a registered env id, without building the env."""
    import gymnasium as gym

    import sim2real.envs as envs

    try:
        env_spec = gym.spec(env_id)
    except gym.error.Error:
        raise ConfigError(
            f"policy {source!r} was trained on {env_id!r}, which this version does not "
            "register (sim2real envs lists the ids)"
        ) from None
    kwargs = {**env_spec.kwargs, **dict(env_kwargs or {})}
    task_name = str(kwargs.get("task", ""))
    task_cls = envs.TASKS.get(task_name)
    if task_cls is None or task_cls.contract is None:
        raise ConfigError(
            f"policy {source!r} ({env_id}) has no deploy contract: deploy runs the arm tasks "
            f"{sorted(n for n, t in envs.TASKS.items() if t.contract is not None)}"
        )
    obs_mode = str(kwargs.get("obs_mode", "state"))
    if obs_mode == "pixels":
        raise ConfigError(f"policy {source!r} observes pixels ({env_id}); deploy feeds state")
    decoder = ActionDecoder(spec, max_delta_rad, use_gripper=task_cls.uses_gripper)
    n_readings = spec.n_joints + (1 if task_cls.uses_gripper else 0)
    builder = ObservationBuilder(
        task_cls().obs_fields(n_readings, decoder.n_actions, obs_mode == "goal")
    )
    steps = int(str(kwargs.get("max_episode_steps", 50)))
    return PolicyIO(task_name, builder, decoder, task_cls.contract, steps)


def policy_io(spec: ArmSpec, meta: PolicyMeta) -> PolicyIO:
    """Pure: the same inputs always give the same builder and decoder; no env is built. The
    layout is checked against the one the policy recorded."""
    env_kwargs = dict(meta.env_kwargs)
    io = io_for(spec, meta.env_id, meta.max_delta_rad, env_kwargs, meta.source)
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
