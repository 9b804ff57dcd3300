"""``sim2real calibrate cube-sheet``: the printed markers decode to their ids at true size."""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.cube import MarkerCube, face_net_layout
from calibration.cube_sheet import PAGES_MM, cube_sheet, sheet_image

DPI = 300.0
PX_PER_MM = DPI / 25.4


def _detect(gray: np.ndarray) -> dict[int, np.ndarray]:
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = detector.detectMarkers(gray)
    assert ids is not None
    return {int(i): c.reshape(4, 2) for c, i in zip(corners, ids.ravel(), strict=True)}


def _side_mm(corners_px: np.ndarray) -> float:
    sides = np.linalg.norm(np.roll(corners_px, -1, axis=0) - corners_px, axis=1)
    return float(sides.mean() / PX_PER_MM)


def test_png_sheet_has_the_five_markers_at_true_size(tmp_path: Path, run_cli) -> None:
    out = tmp_path / "cube.png"
    code, stdout, _ = run_cli("cube-sheet", "--out", str(out), "--dpi", str(DPI))
    assert code == 0 and "cube side 25.0 mm" in stdout and "[2, 3, 4, 5, 6]" in stdout
    png = out.read_bytes()
    # The pHYs chunk carries the DPI (pixels per metre), so the image prints at true size.
    at = png.index(b"pHYs")
    assert int.from_bytes(png[at + 4 : at + 8], "big") == round(DPI / 0.0254)
    gray = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert gray.shape == (round(297 * PX_PER_MM), round(210 * PX_PER_MM))
    found = _detect(gray)
    assert sorted(found) == [2, 3, 4, 5, 6]
    for corners in found.values():
        assert _side_mm(corners) == pytest.approx(20.0, abs=0.15)
    # The top face (id 2) is in the middle of the net: 25 mm from each side face's centre.
    centre = found[2].mean(axis=0)
    for i in (3, 4, 5, 6):
        assert np.linalg.norm(found[i].mean(axis=0) - centre) / PX_PER_MM == pytest.approx(
            25.0, abs=0.2
        )


def test_side_markers_point_up_at_the_top_face(tmp_path: Path, run_cli) -> None:
    """ArUco's corner order gives each printed marker's own "up"; after folding it must point at
    the top face, as the tracker's face frames assume."""
    out = tmp_path / "cube.png"
    assert run_cli("cube-sheet", "--out", str(out), "--dpi", "200")[0] == 0
    found = _detect(cv2.imread(str(out), cv2.IMREAD_GRAYSCALE))
    centre = found[2].mean(axis=0)
    for i in (3, 4, 5, 6):
        tl, tr, br, bl = found[i]
        up = (tl + tr) / 2 - (bl + br) / 2  # image pixels (y down)
        towards = centre - found[i].mean(axis=0)
        cos = float(up @ towards / np.linalg.norm(up) / np.linalg.norm(towards))
        assert cos > 0.99, i


def test_pdf_sheet_is_vector_markers_at_true_size(tmp_path: Path, run_cli) -> None:
    out = tmp_path / "cube.pdf"
    code, stdout, _ = run_cli("cube-sheet", "--out", str(out), "--json")
    assert code == 0 and '"marker_side_m": 0.02' in stdout
    pdf = out.read_bytes()
    assert pdf.startswith(b"%PDF-1.4") and pdf.rstrip().endswith(b"%%EOF")
    # Every xref entry points at its object.
    start = int(re.search(rb"startxref\n(\d+)", pdf).group(1))  # type: ignore[union-attr]
    entries = re.findall(rb"(\d{10}) 00000 n", pdf[start:])
    for number, offset in enumerate(entries, start=1):
        assert pdf[int(offset) :].startswith(f"{number} 0 obj".encode())
    width_pt, height_pt = (
        float(v) for v in re.search(rb"MediaBox \[0 0 ([\d.]+) ([\d.]+)\]", pdf).groups()
    )  # type: ignore[union-attr]
    assert width_pt / 72 * 25.4 == pytest.approx(210.0, abs=0.01)
    stream = pdf[pdf.index(b"stream\n") + 7 : pdf.index(b"\nendstream")]
    ops = zlib.decompress(stream).decode()
    # Rasterise the filled rectangles (PDF points, origin bottom-left) and decode the markers.
    k = DPI / 72.0
    img = np.full((round(height_pt * k), round(width_pt * k)), 255, np.uint8)
    for x, y, w, h in re.findall(r"([\d.]+) ([\d.]+) ([\d.]+) ([\d.]+) re f", ops):
        x0, x1 = round(float(x) * k), round((float(x) + float(w)) * k)
        y1, y0 = round(img.shape[0] - float(y) * k), round(img.shape[0] - (float(y) + float(h)) * k)
        img[y0:y1, x0:x1] = 0
    found = _detect(img)
    assert sorted(found) == [2, 3, 4, 5, 6]
    for corners in found.values():
        assert _side_mm(corners) == pytest.approx(20.0, abs=0.15)
    assert "(Cube side 25.0 mm; marker \\(black square\\) 20.0 mm; DICT_4X4_50) Tj" in ops


def test_other_sizes_and_pages_lay_out_within_the_page() -> None:
    cube = MarkerCube(size_m=0.05, marker_m=0.04, face_ids=(10, 11, 12, 13, 14))
    for page in PAGES_MM:
        sheet = cube_sheet(cube, page)
        w, h = sheet.page_mm
        for box in sheet.boxes:
            assert box.x_mm >= 0 and box.x_mm + box.w_mm <= w and box.y_mm + box.h_mm <= h
        assert sorted(sheet.markers_mm) == sorted(face_net_layout(cube))
    img = sheet_image(cube_sheet(cube), 100.0)
    assert sorted(_detect(img)) == [10, 11, 12, 13, 14]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (("--out", "cube.jpg"), "written as .pdf or .png"),
        (("--out", "cube.pdf", "--marker-m", "0.03"), "marker_m 0.03 must be in"),
        (("--out", "cube.pdf", "--ids", "2,3,x"), "five integers"),
        (("--out", "cube.pdf", "--ids", "2,3,4,5,99"), "marker id 99 is not an id of"),
        (("--out", "cube.pdf", "--size-m", "0.08"), "does not fit on a4"),
        (("--out", "cube.png", "--dpi", "10"), "dpi must be in"),
    ],
)
def test_bad_sheet_options_fail_in_one_line_and_write_nothing(
    tmp_path: Path, run_cli, argv: tuple[str, ...], message: str
) -> None:
    argv = tuple(str(tmp_path / a) if a.startswith("cube.") else a for a in argv)
    code, _, err = run_cli("cube-sheet", *argv)
    assert code == 2 and message in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())
