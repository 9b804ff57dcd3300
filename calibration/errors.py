"""Exceptions of the calibration package.

Kept import-light (no cv2, no numpy) because the CLI's ``main`` imports it on every command. Every
message names the offending value and, where there is a fixed set, lists the valid choices, so the
CLI can print it as one line and exit non-zero.
"""

from __future__ import annotations

from collections.abc import Iterable


class CalibrationError(Exception):
    """Base class: the CLI prints these as one line and exits 2."""


class UnknownNameError(CalibrationError, KeyError):
    """A name that is not in a registry (board kind, ArUco dictionary, distortion model...)."""

    def __init__(self, kind: str, name: str, valid: Iterable[str]) -> None:
        self.kind, self.name, self.valid = kind, name, sorted(valid)
        super().__init__(f"unknown {kind} {name!r}; valid: {', '.join(self.valid)}")

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class BoardSpecError(CalibrationError, ValueError):
    """A ``--board`` string or board geometry is malformed."""


class ImageError(CalibrationError):
    """An image folder is empty, an image is unreadable or corrupt, or pairs do not match."""


class BoardNotFoundError(CalibrationError):
    """No usable board in the images (or too few views to calibrate)."""


class CalibrationFileError(CalibrationError):
    """A calibration/registration file is missing, unreadable or incomplete."""


class ConfigError(CalibrationError, ValueError):
    """A configuration value is out of range or inconsistent."""


class CaptureError(CalibrationError):
    """A camera cannot be opened or stops delivering frames."""


class RegistrationError(CalibrationError):
    """Too few or degenerate correspondences to register the camera to the arm."""
