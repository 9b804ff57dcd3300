"""Runs inside the separate LeRobot venv, started by bench/lerobot_dataset.py (``make bench``
does not run this folder): loads a dataset with LeRobot's own ``LeRobotDataset`` and prints one
JSON object of what it found.

Usage: lerobot_check.py DATASET_DIR REFERENCE.npz
REFERENCE.npz holds, per checked (episode, frame, camera), the frame our own reader decoded;
the loader's frame for the same index must match it (same episode offset, same step).
"""

from __future__ import annotations

import json
import os
import sys
from importlib.metadata import version

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a local dataset: nothing is fetched


def main() -> None:
    import numpy as np
    from ledataset.datasets.lerobot_dataset import LeRobotDataset

    root, ref_path = sys.argv[1], sys.argv[2]
    ds = LeRobotDataset("local/sim2real", root=root, video_backend="pyav")
    ref = np.load(ref_path)
    worst = 0.0
    checked = 0
    for key in ref.files:
        ep, frame, cam = key.split("|")
        row = int(ds.meta.episodes[int(ep)]["dataset_from_index"]) + int(frame)
        item = ds[row]
        assert int(item["episode_index"]) == int(ep) and int(item["frame_index"]) == int(frame)
        got = item[cam].numpy()  # (3, H, W) float in [0, 1]
        want = ref[key].astype(np.float64).transpose(2, 0, 1) / 255.0
        worst = max(worst, float(np.abs(got - want).mean()))
        checked += 1
    first = ds[0]
    # How policies train on it: action chunks and a short image history, by timestamp offsets.
    dt = 1.0 / ds.fps
    chunked = LeRobotDataset(
        "local/sim2real",
        root=root,
        video_backend="pyav",
        delta_timestamps={
            "action": [i * dt for i in range(8)],
            "observation.images.cam_left": [-dt, 0.0],
        },
    )
    mid = chunked[int(chunked.meta.episodes[0]["dataset_to_index"]) - 3]  # near an episode end
    print(
        json.dumps(
            {
                "versions": {
                    p: version(p)
                    for p in (
                        "lerobot-dataset",
                        "torch",
                        "torchvision",
                        "av",
                        "datasets",
                        "pyarrow",
                    )
                },
                "codebase_version": ds.meta.info["codebase_version"],
                "num_episodes": ds.num_episodes,
                "num_frames": ds.num_frames,
                "len": len(ds),
                "fps": ds.fps,
                "features": sorted(ds.features),
                "video_keys": list(ds.meta.video_keys),
                "task": first["task"],
                "state_shape": list(first["observation.state"].shape),
                "action_chunk_shape": list(mid["action"].shape),
                "action_chunk_padded": int(mid["action_is_pad"].sum()),
                "image_history_shape": list(mid["observation.images.cam_left"].shape),
                "video_frames_checked": checked,
                "video_mean_abs_diff": worst,
            }
        )
    )


if __name__ == "__main__":
    main()
