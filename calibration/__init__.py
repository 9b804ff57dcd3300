"""Camera calibration and two-camera perception: numpy, OpenCV and filterpy only.

This file imports nothing heavy, because ``sim2real``'s CLI imports ``calibration.errors`` on
every command; the public names below load their module on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS: dict[str, str] = {
    "CalibrationError": "calibration.errors",
    "CameraModel": "calibration.camera",
    "StereoRig": "calibration.triangulate",
    "parse_board": "calibration.boards",
    "calibrate_camera": "calibration.intrinsics",
    "calibrate_stereo": "calibration.stereo",
    "check_stereo": "calibration.check",
    "ArucoMarkerDetector": "calibration.markers",
    "ColorBlobDetector": "calibration.markers",
    "KalmanTracker": "calibration.kalman",
    "TrackerConfig": "calibration.kalman",
    "StereoMarkerTracker": "calibration.perception",
    "StereoBlobTracker": "calibration.perception",
    "register": "calibration.registration",
    "load_base_T_cam": "calibration.registration",
    "Camera": "calibration.capture",
    "OpenCVCamera": "calibration.capture",
    "ReplayCamera": "calibration.capture",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'calibration' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)
