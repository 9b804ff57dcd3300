"""Calibration boards: the ``--board`` string, a registry of board kinds, detection and textures.

``chessboard:COLSxROWS:SQUARE`` counts *inner corners* (OpenCV's ``patternSize``);
``charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy|:new]`` counts *squares* (OpenCV's CharucoBoard
size). Sizes are in the unit the user wants the results in (metres by convention).

Every detection is returned in a canonical corner order so two cameras (and two views) agree on
which corner is which. ChArUco ids make that trivial; for a chessboard the order is fixed by
handedness (mirror) and by the colour of the first square (180° turn), which only works when the
board is not point-symmetric, i.e. when ``cols + rows`` is odd. Even-sum chessboards are flagged
``point_symmetric`` and the stereo code aligns each pair geometrically instead.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, cast

import cv2
import numpy as np

from calibration.errors import BoardSpecError, UnknownNameError

# No CALIB_CB_FAST_CHECK: it rejected 4 of the 50 real images that the full search finds.
_CHESS_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 1e-3)
MIN_CHARUCO_CORNERS = 6  # calibrateCamera needs ≥ 4 non-collinear points; 6 gives margin


def aruco_dictionaries() -> dict[str, int]:
    """Registry of the predefined ArUco dictionaries: ``DICT_4X4_50`` → OpenCV id."""
    return {
        name: int(getattr(cv2.aruco, name))
        for name in dir(cv2.aruco)
        if name.startswith("DICT_") and isinstance(getattr(cv2.aruco, name), int)
    }


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """Look a dictionary up by name; ``4x4_50`` and ``DICT_4X4_50`` are both accepted."""
    table = aruco_dictionaries()
    key = name.strip().upper()
    key = key if key.startswith("DICT_") else f"DICT_{key}"
    if key not in table:
        raise UnknownNameError("ArUco dictionary", name, table)
    return cv2.aruco.getPredefinedDictionary(table[key])


def canonical_dictionary_name(name: str) -> str:
    key = name.strip().upper()
    key = key if key.startswith("DICT_") else f"DICT_{key}"
    aruco_dictionary(key)  # validates
    return key


@dataclass(frozen=True, eq=False)
class Detection:
    """Board corners found in one image, in the board's canonical order.

    ``image_points`` (N,2) float32 px; ``object_points`` (N,3) float32 in board units;
    ``ids`` (N,) int32: the corner index on the board (row-major for a chessboard).
    """

    image_points: np.ndarray
    object_points: np.ndarray
    ids: np.ndarray
    layout: str = ""  # ChArUco: "new" or "legacy"

    def __post_init__(self) -> None:
        n = len(self.ids)
        if self.image_points.shape != (n, 2) or self.object_points.shape != (n, 3):
            raise ValueError("image_points, object_points and ids disagree in length")

    def __len__(self) -> int:
        return len(self.ids)

    def subset(self, ids: np.ndarray) -> Detection:
        """The corners whose id is in ``ids``, in the order of ``ids``."""
        index = {int(i): k for k, i in enumerate(self.ids)}
        rows = np.array([index[int(i)] for i in ids], dtype=np.int64)
        return Detection(
            self.image_points[rows], self.object_points[rows], self.ids[rows], self.layout
        )

    def reversed(self) -> Detection:
        """A full chessboard grid turned by 180°: corner k becomes corner N-1-k."""
        return Detection(self.image_points[::-1].copy(), self.object_points, self.ids, self.layout)


class BoardSpec(Protocol):
    """What the calibration code needs from a board kind."""

    kind: ClassVar[str]

    @property
    def square(self) -> float:
        """Square edge length, in the unit the results are wanted in."""
        ...

    @property
    def point_symmetric(self) -> bool:
        """True when a 180° turn of the board looks the same (corner order is ambiguous)."""
        ...

    @property
    def corner_count(self) -> int: ...

    def object_points(self) -> np.ndarray:
        """All corners (M,3) in board units, indexed by corner id."""
        ...

    def detect(self, gray: np.ndarray) -> Detection | None:
        """Find the board in a grayscale uint8 image; ``None`` when it is not there."""
        ...

    def diagnose_missing(self, grays: list[np.ndarray]) -> str:
        """Why the board was found in none of ``grays``: a hint for the one-line error."""
        ...

    def texture(self, px_per_square: int) -> tuple[np.ndarray, np.ndarray]:
        """A printable image of the board and the 3×3 map from board units to its pixels."""
        ...

    def __str__(self) -> str: ...


# ------------------------------------------------------------------------------ chessboard
@dataclass(frozen=True)
class ChessboardSpec:
    """A plain chessboard: ``cols``×``rows`` *inner* corners, ``square`` edge length."""

    kind: ClassVar[str] = "chessboard"
    cols: int
    rows: int
    square: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise BoardSpecError(
                f"chessboard {self.cols}x{self.rows}: needs at least 3x3 inner corners"
            )
        if self.cols == self.rows:
            raise BoardSpecError(
                f"chessboard {self.cols}x{self.rows} is square: its corner order is ambiguous "
                "between views; use a board whose inner-corner counts differ (e.g. 9x6)"
            )
        _check_length("square size", self.square)

    def __str__(self) -> str:
        return f"chessboard:{self.cols}x{self.rows}:{self.square:g}"

    @property
    def point_symmetric(self) -> bool:
        return (self.cols + self.rows) % 2 == 0

    @property
    def corner_count(self) -> int:
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square
        return pts.astype(np.float32)

    def _find(self, gray: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
        found, corners = cv2.findChessboardCorners(gray, (cols, rows), flags=_CHESS_FLAGS)
        if not found:
            return None
        return np.asarray(corners, dtype=np.float32).reshape(-1, 2)

    def detect(self, gray: np.ndarray) -> Detection | None:
        corners = self._find(gray, self.cols, self.rows)
        if corners is None:
            return None
        grid = corners.reshape(self.rows, self.cols, 2)
        # cornerSubPix's window must stay inside one square: 40% of the corner spacing, ≤ 11.
        spacing = min(
            float(np.min(np.linalg.norm(np.diff(grid, axis=1), axis=2))),
            float(np.min(np.linalg.norm(np.diff(grid, axis=0), axis=2))),
        )
        half = int(np.clip(round(0.4 * spacing), 2, 11))
        refined = cv2.cornerSubPix(
            gray, corners.reshape(-1, 1, 2).copy(), (half, half), (-1, -1), _SUBPIX_CRITERIA
        ).reshape(self.rows, self.cols, 2)
        refined = _canonical_grid(refined, gray, colour_check=not self.point_symmetric)
        ids = np.arange(self.corner_count, dtype=np.int32)
        return Detection(refined.reshape(-1, 2).astype(np.float32), self.object_points(), ids)

    def diagnose_missing(self, grays: list[np.ndarray]) -> str:
        """Try the sizes people give by mistake: squares instead of inner corners, swapped."""
        tried = {(self.cols - 1, self.rows - 1): "squares", (self.cols - 2, self.rows - 2): "edge"}
        for gray in grays:
            for (cols, rows), cause in tried.items():
                if cols < 3 or rows < 3 or self._find(gray, cols, rows) is None:
                    continue
                if cause == "squares":
                    return (
                        f"a {cols}x{rows} chessboard was found instead: --board counts inner "
                        f"corners, not squares (a board of {self.cols}x{self.rows} squares has "
                        f"{cols}x{rows} inner corners); use chessboard:{cols}x{rows}:"
                        f"{self.square:g}"
                    )
                return (
                    f"a {cols}x{rows} chessboard was found instead; use chessboard:"
                    f"{cols}x{rows}:{self.square:g} (inner corners)"
                )
        return (
            f"check the size: {self.cols}x{self.rows} counts inner corners (a board of "
            f"{self.cols + 1}x{self.rows + 1} squares), and the board needs a white border"
        )

    def texture(self, px_per_square: int) -> tuple[np.ndarray, np.ndarray]:
        """Black first square at the top-left, one white square of margin all round."""
        n_x, n_y = self.cols + 1, self.rows + 1
        margin = px_per_square
        img = np.full((n_y * px_per_square + 2 * margin, n_x * px_per_square + 2 * margin), 255)
        for r in range(n_y):
            for c in range(n_x):
                if (r + c) % 2 == 0:
                    y0, x0 = margin + r * px_per_square, margin + c * px_per_square
                    img[y0 : y0 + px_per_square, x0 : x0 + px_per_square] = 0
        # Corner (0,0) sits one square in from the board edge; pixel centres are integers.
        scale = px_per_square / self.square
        offset = margin + px_per_square - 0.5
        tex_from_board = np.array([[scale, 0, offset], [0, scale, offset], [0, 0, 1.0]])
        return img.astype(np.uint8), tex_from_board


def _canonical_grid(grid: np.ndarray, gray: np.ndarray, colour_check: bool) -> np.ndarray:
    """Put a (rows, cols, 2) corner grid in canonical order.

    1. Handedness: board x (along a row) × board y (down the columns) must point away from the
       camera, i.e. a positive 2-D cross product in image coordinates; otherwise mirror the rows.
    2. Colour: the square between corners (0,0) and (1,1) is black; otherwise turn by 180°.
    """
    d_x = (grid[:, -1] - grid[:, 0]).mean(axis=0)
    d_y = (grid[-1, :] - grid[0, :]).mean(axis=0)
    if d_x[0] * d_y[1] - d_x[1] * d_y[0] < 0:
        grid = grid[:, ::-1]
    if colour_check:
        centres = 0.25 * (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:])
        h, w = gray.shape[:2]
        xs = np.clip(np.rint(centres[..., 0]).astype(int), 0, w - 1)
        ys = np.clip(np.rint(centres[..., 1]).astype(int), 0, h - 1)
        values = gray[ys, xs].astype(np.float64)
        parity = np.add.outer(np.arange(values.shape[0]), np.arange(values.shape[1])) % 2
        if values[parity == 0].mean() > values[parity == 1].mean():
            grid = grid[::-1, ::-1]
    return np.ascontiguousarray(grid)


# ------------------------------------------------------------------------------ ChArUco
@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board: ``cols``×``rows`` *squares*, square and marker edge, ArUco dictionary.

    ``legacy`` picks the marker layout: True for boards printed with OpenCV < 4.6 (which differ
    when ``rows`` is even), False for the current one, None to try both and keep what matches.
    """

    kind: ClassVar[str] = "charuco"
    cols: int
    rows: int
    square: float
    marker: float
    dictionary: str = "DICT_4X4_50"
    legacy: bool | None = None
    _boards: dict[bool, cv2.aruco.CharucoBoard] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )
    _detectors: dict[bool, cv2.aruco.CharucoDetector] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise BoardSpecError(f"charuco {self.cols}x{self.rows}: needs at least 3x3 squares")
        _check_length("square size", self.square)
        _check_length("marker size", self.marker)
        if self.marker >= self.square:
            raise BoardSpecError(
                f"charuco marker size {self.marker:g} must be smaller than the square size "
                f"{self.square:g}"
            )
        name = canonical_dictionary_name(self.dictionary)
        object.__setattr__(self, "dictionary", name)
        dictionary = aruco_dictionary(name)
        needed = (self.cols * self.rows) // 2
        available = int(dictionary.bytesList.shape[0])
        if needed > available:
            raise BoardSpecError(
                f"dictionary {name} has {available} markers; a {self.cols}x{self.rows} "
                f"ChArUco board needs {needed}"
            )
        for legacy in (False, True):
            board = cv2.aruco.CharucoBoard(
                (self.cols, self.rows), self.square, self.marker, dictionary
            )
            board.setLegacyPattern(legacy)
            self._boards[legacy] = board
            self._detectors[legacy] = cv2.aruco.CharucoDetector(board)

    def __str__(self) -> str:
        layout = {None: "", True: ":legacy", False: ":new"}[self.legacy]
        return (
            f"charuco:{self.cols}x{self.rows}:{self.square:g}:{self.marker:g}:"
            f"{self.dictionary}{layout}"
        )

    @property
    def point_symmetric(self) -> bool:
        return False  # marker ids fix the order

    @property
    def corner_count(self) -> int:
        return (self.cols - 1) * (self.rows - 1)

    def object_points(self) -> np.ndarray:
        return np.asarray(self._boards[False].getChessboardCorners(), dtype=np.float32)

    def _layouts(self) -> tuple[bool, ...]:
        return (False, True) if self.legacy is None else (self.legacy,)

    def detect(self, gray: np.ndarray) -> Detection | None:
        best: Detection | None = None
        for legacy in self._layouts():
            corners, ids, marker_corners, marker_ids = self._detectors[legacy].detectBoard(gray)
            if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
                if marker_ids is None:
                    return None  # no markers at all: the other layout cannot do better
                continue
            board = self._boards[legacy]
            if board.checkCharucoCornersCollinear(ids):
                continue
            corners = self._refine(gray, corners, marker_corners)
            # The stubs only know the marker-board overload; ChArUco takes a corner array.
            obj, img = cast(Any, board).matchImagePoints(corners, ids)
            det = Detection(
                np.asarray(img, np.float32).reshape(-1, 2),
                np.asarray(obj, np.float32).reshape(-1, 3),
                np.asarray(ids, np.int32).ravel(),
                "legacy" if legacy else "new",
            )
            if best is None or len(det) > len(best):
                best = det
        return best

    def _refine(
        self, gray: np.ndarray, corners: np.ndarray, marker_corners: Sequence[np.ndarray]
    ) -> np.ndarray:
        """Sub-pixel corners with a window that stays in the gap between square and marker.

        The detector's own refinement uses a window that reaches into the markers and biases the
        corners by ~0.5 px on rendered boards; measured here, a window inside the gap is ~0.01 px.
        """
        sides = [
            float(np.linalg.norm(np.diff(np.asarray(m).reshape(4, 2), axis=0), axis=1).mean())
            for m in marker_corners
        ]
        gap_px = float(np.median(sides)) * (self.square - self.marker) / (2.0 * self.marker)
        half = int(np.clip(np.floor(0.75 * gap_px), 1, 11))
        return cv2.cornerSubPix(gray, corners.copy(), (half, half), (-1, -1), _SUBPIX_CRITERIA)

    def diagnose_missing(self, grays: list[np.ndarray]) -> str:
        detector = cv2.aruco.ArucoDetector(aruco_dictionary(self.dictionary))
        for gray in grays:
            _, ids, _ = detector.detectMarkers(gray)
            if ids is not None and len(ids):
                layouts = "either layout" if self.legacy is None else "this layout"
                return (
                    f"{len(ids)} {self.dictionary} markers were found but no ChArUco corners "
                    f"with {layouts}: check COLSxROWS ({self.cols}x{self.rows} counts squares, "
                    "not inner corners) and the legacy/new layout"
                )
        return (
            f"no {self.dictionary} marker was found: check the dictionary "
            f"(valid: DICT_4X4_50, DICT_5X5_100, ...) and the lighting"
        )

    def texture(self, px_per_square: int) -> tuple[np.ndarray, np.ndarray]:
        margin = px_per_square
        size = (self.cols * px_per_square + 2 * margin, self.rows * px_per_square + 2 * margin)
        board = self._boards[bool(self.legacy)]
        img = board.generateImage(size, marginSize=margin, borderBits=1)
        scale = px_per_square / self.square
        offset = margin - 0.5
        tex_from_board = np.array([[scale, 0, offset], [0, scale, offset], [0, 0, 1.0]])
        return np.asarray(img, np.uint8), tex_from_board


# ------------------------------------------------------------------------------ parsing
def _check_length(what: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise BoardSpecError(f"{what} must be a positive number, got {value!r}")


_SIZE_RE = re.compile(r"^(\d+)[xX](\d+)$")


def _parse_size(text: str, spec: str) -> tuple[int, int]:
    match = _SIZE_RE.match(text.strip())
    if not match:
        raise BoardSpecError(f"board {spec!r}: size {text!r} must look like 9x6")
    return int(match.group(1)), int(match.group(2))


def _parse_length(text: str, what: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise BoardSpecError(f"board {spec!r}: {what} {text!r} is not a number") from None
    _check_length(f"board {spec!r}: {what}", value)
    return value


def _parse_chessboard(fields: list[str], spec: str) -> BoardSpec:
    if len(fields) != 2:
        raise BoardSpecError(f"board {spec!r}: expected chessboard:COLSxROWS:SQUARE")
    cols, rows = _parse_size(fields[0], spec)
    return ChessboardSpec(cols, rows, _parse_length(fields[1], "square size", spec))


_LAYOUTS: dict[str, bool | None] = {"legacy": True, "new": False, "auto": None}


def _parse_charuco(fields: list[str], spec: str) -> BoardSpec:
    if len(fields) not in (4, 5):
        raise BoardSpecError(
            f"board {spec!r}: expected charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy|:new]"
        )
    cols, rows = _parse_size(fields[0], spec)
    square = _parse_length(fields[1], "square size", spec)
    marker = _parse_length(fields[2], "marker size", spec)
    layout = fields[4].lower() if len(fields) == 5 else "auto"
    if layout not in _LAYOUTS:
        raise UnknownNameError("ChArUco layout", fields[4], _LAYOUTS)
    return CharucoSpec(cols, rows, square, marker, fields[3], _LAYOUTS[layout])


BOARD_KINDS: dict[str, Callable[[list[str], str], BoardSpec]] = {
    "chessboard": _parse_chessboard,
    "charuco": _parse_charuco,
}


def parse_board(spec: str) -> BoardSpec:
    """Parse a ``--board`` string (see the module docstring for the grammar)."""
    kind, _, rest = spec.strip().partition(":")
    if kind.lower() not in BOARD_KINDS:
        raise UnknownNameError("board kind", kind, BOARD_KINDS)
    return BOARD_KINDS[kind.lower()](rest.split(":") if rest else [], spec)
