"""Recorded rollouts in the formats other tools read (LeRobot v3.0)."""

from sim2real.datasets.lerobot import (
    CODEBASE_VERSION,
    TASK_TEXT,
    DatasetError,
    DatasetSchema,
    Feature,
    LeRobotDataset,
    LeRobotWriter,
    arm_features,
    arm_frames,
    camera_key,
    split_episodes,
)

__all__ = [
    "CODEBASE_VERSION",
    "TASK_TEXT",
    "DatasetError",
    "DatasetSchema",
    "Feature",
    "LeRobotDataset",
    "LeRobotWriter",
    "arm_features",
    "arm_frames",
    "camera_key",
    "split_episodes",
]
