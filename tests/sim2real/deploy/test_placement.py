"""RigSight: a placement is kept only if the rig's rendered cameras find its objects (real MuJoCo
rendering, real ArUco detection and triangulation on the frames)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from hardware.spec import ArmSpec
from sim2real import model as names
from sim2real.deploy.placement import RigSight
from sim2real.envs.trace import TraceContract


@pytest.fixture(scope="module")
def sight(spec: ArmSpec) -> Iterator[RigSight]:
    s = RigSight(spec, "trace", TraceContract.objects)
    yield s
    s.close()


def test_a_seam_whose_end_plate_lies_under_the_arm_base_is_not_seen(sight: RigSight) -> None:
    """An env seam that heads back towards the arm: its end plate lands under the base."""
    start_xy, heading = np.array([0.166, 0.044]), -2.812
    end_plate = start_xy + (names.SEAM_LENGTH_M + names.SEAM_MARKERS.end_offset_m) * np.array(
        [np.cos(heading), np.sin(heading)]
    )
    assert np.linalg.norm(end_plate) < 0.045  # inside the base's 45 mm radius
    why = sight.unseen({"seam": np.array([*start_xy, heading])})
    assert why is not None and "seam_end" in why
    end_id = names.SEAM_MARKERS.end_id
    assert (
        f"left [1, {names.SEAM_MARKERS.start_id}]" in why and str(end_id) not in why.split("(")[1]
    )


def test_a_seam_in_front_of_the_arm_is_seen(sight: RigSight) -> None:
    assert sight.unseen({"seam": np.array([0.12, 0.0, 0.0])}) is None
    assert sight.unseen({"seam": np.array([0.15, 0.05, -1.6])}) is None
