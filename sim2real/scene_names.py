"""Names and marker geometry shared by the MuJoCo model, the envs and the deploy loop.

They live apart from ``sim2real.model`` (which builds the MJCF and imports MuJoCo) so that the
deploy runtime on a computer without MuJoCo reads the same marker ids and sizes; ``model``
re-exports every name.
"""

from __future__ import annotations

from typing import Literal

from calibration.cube import MarkerCube, SeamMarkers

Scene = Literal["reach", "pick", "trace"]
SCENES: tuple[str, ...] = ("reach", "pick", "trace")

# Names shared by the model, the envs and the deploy loop (resolved to ids once per model).
TOOL_SITE = "tool"
TARGET_BODY = "target"
TARGET_SITE = "target"
CUBE_BODY = "cube"
CUBE_GEOM = "cube"
CUBE_JOINT = "cube_free"
WRIST_JOINT = "wrist_level"
FINGER_JOINTS = ("finger_left", "finger_right")
FINGER_GEOMS = ("finger_left", "finger_right")
TABLE_GEOM = "table"
LINK_ROOT_BODY = "upper_arm"  # the first link the shoulder moves: it and below can hit the table
LEVEL_TENDON = "gripper_level"
MARKER_GEOM = "target_marker"
TARGET_PLATE_GEOM = "target_plate"
TARGET_STAND_GEOM = "target_stand"  # the post a pixel reach target stands on (opt-in)
EE_MARKER_GEOM = "ee_marker"
PATH_GEOM_PREFIX = "seam_"
SEAM_BODY = "seam"
SEAM_LENGTH_M = 0.12
SEAM_BODY_Z_M = 0.0003  # the seam's line sits just above the table (no z-fighting)

# ArUco markers for the camera pipeline (deploy scenes): DICT_4X4_50 ids, black square side.
MARKER_DICTIONARY = "DICT_4X4_50"
TARGET_MARKER_ID = 0
EE_MARKER_ID = 1
TARGET_MARKER_SIZE_M = 0.04
EE_MARKER_SIZE_M = 0.03
MARKER_TEXTURE_PX = 96  # texture side; the black square covers MARKER_FILL of it
MARKER_FILL = 0.75
# Where the ee marker sits on the wrist body (plate centre, on a riser above the wrist link),
# tilted forward so the cameras in front never see it edge-on (a flat plate is unreadable when
# the gripper is high and the view grazes it).
EE_MARKER_POS_M = (0.02, 0.0, 0.022)
EE_MARKER_TILT_RAD = 0.7
# The pick cube's face markers and the trace seam's end plates (deploy scenes only): their
# geometry is shared with the tracker and the printable sheet, so it lives in calibration.
MARKER_CUBE = MarkerCube(size_m=0.025, marker_m=0.02, face_ids=(2, 3, 4, 5, 6))
CUBE_MARKER_TEXTURE_PX = 120  # 96 px of black square: 16 px per ArUco module (6 x 6)
CUBE_MARKER_GEOM_PREFIX = "cube_marker_"
SEAM_MARKERS = SeamMarkers(start_id=7, end_id=8, marker_m=0.03, end_offset_m=0.027)
SEAM_MARKER_GEOM_PREFIX = "seam_marker_"
