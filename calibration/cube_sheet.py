"""The printable marker cube: a net of its five marked faces at true size, as PDF or PNG.

The sheet is a list of primitives in millimetres (page origin top-left, y down) drawn by two
small writers: a vector PDF (every ArUco module is an exact filled square, no resampling by the
printer driver) and a raster PNG at a stated DPI, with the DPI written into the file so image
viewers and printers keep the true size. No dependency beyond numpy and OpenCV.

The net (``calibration.cube.face_net_layout``): the top face in the centre and the four side
faces around it, each side marker turned so its "up" points at the top face. Cut along the solid
lines, fold along the dashed ones, printed side out; the two tabs on the ±x faces glue under the
±y faces. Or cut the five squares apart and glue them on a wooden cube of the same side.
"""

from __future__ import annotations

import itertools
import zlib
from dataclasses import dataclass, field

import cv2
import numpy as np

from calibration.boards import aruco_dictionary
from calibration.cube import FACE_NAMES, MarkerCube, face_net_layout
from calibration.errors import ConfigError

MM_PER_INCH = 25.4
PT_PER_MM = 72.0 / MM_PER_INCH
PAGES_MM: dict[str, tuple[float, float]] = {"a4": (210.0, 297.0), "letter": (215.9, 279.4)}
MARGIN_MM = 15.0
TAB_MM = 6.0
SCALE_BAR_MM = 100.0


@dataclass(frozen=True)
class Box:
    """A filled black rectangle."""

    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float


@dataclass(frozen=True)
class Line:
    x0_mm: float
    y0_mm: float
    x1_mm: float
    y1_mm: float
    dashed: bool = False
    width_mm: float = 0.2


@dataclass(frozen=True)
class Text:
    """One line of ASCII text; (x, y) is the left end of its baseline."""

    x_mm: float
    y_mm: float
    size_pt: float
    text: str


@dataclass(frozen=True)
class Sheet:
    page_mm: tuple[float, float]
    boxes: list[Box] = field(default_factory=list)
    lines: list[Line] = field(default_factory=list)
    texts: list[Text] = field(default_factory=list)
    # Where each marker's black square is on the page: id → (x, y, side) in mm.
    markers_mm: dict[int, tuple[float, float, float]] = field(default_factory=dict)


def marker_bits(dictionary: str, marker_id: int) -> np.ndarray:
    """(n, n) bool, True = black module, border included (6×6 for a 4×4 dictionary)."""
    d = aruco_dictionary(dictionary)
    n = int(d.markerSize) + 2
    img = cv2.aruco.generateImageMarker(d, marker_id, n, borderBits=1)
    return np.asarray(img < 128)


def _tab(x0: float, y0: float, x1: float, y1: float, outward: tuple[float, float]) -> list[Line]:
    """A glue tab on the edge (x0,y0)-(x1,y1): a trapezoid folded along the edge."""
    ox, oy = outward[0] * TAB_MM, outward[1] * TAB_MM
    ex, ey = (x1 - x0) * 0.2, (y1 - y0) * 0.2
    pts = [(x0, y0), (x0 + ex + ox, y0 + ey + oy), (x1 - ex + ox, y1 - ey + oy), (x1, y1)]
    lines = [Line(*pts[i], *pts[i + 1]) for i in range(3)]
    lines.append(Line(x0, y0, x1, y1, dashed=True))
    return lines


def cube_sheet(cube: MarkerCube, page: str = "a4") -> Sheet:
    """Lay out the net of ``cube`` centred on a ``page`` ('a4' or 'letter'), with its sizes."""
    if page not in PAGES_MM:
        raise ConfigError(f"unknown page {page!r}; choose one of {', '.join(PAGES_MM)}")
    width, height = PAGES_MM[page]
    s = cube.size_m * 1000.0
    net_w = 3 * s
    if net_w + 2 * TAB_MM > width - 2 * MARGIN_MM or 3 * s + 2 * TAB_MM > height - 110.0:
        raise ConfigError(
            f"a cube of side {s:.1f} mm does not fit on {page}: its net is {net_w:.0f} mm wide"
        )
    sheet = Sheet((width, height))
    x0 = (width - net_w) / 2
    y0 = 95.0
    bits_px = marker_bits(cube.dictionary, cube.face_ids[0]).shape[0]
    module = cube.marker_m * 1000.0 / bits_px
    margin = (s - cube.marker_m * 1000.0) / 2
    layout = face_net_layout(cube)
    for marker_id, ((col, row), turns) in layout.items():
        fx, fy = x0 + col * s, y0 + row * s
        bits = np.rot90(marker_bits(cube.dictionary, marker_id), k=turns)
        mx, my = fx + margin, fy + margin
        sheet.markers_mm[marker_id] = (mx, my, cube.marker_m * 1000.0)
        for r in range(bits.shape[0]):
            c = 0
            while c < bits.shape[1]:  # one box per horizontal run of black modules
                if not bits[r, c]:
                    c += 1
                    continue
                start = c
                while c < bits.shape[1] and bits[r, c]:
                    c += 1
                sheet.boxes.append(
                    Box(mx + start * module, my + r * module, (c - start) * module, module)
                )
    # Cut lines: the outline of the cross; fold lines: the top face's four edges.
    a, b, c3, d = x0, x0 + s, x0 + 2 * s, x0 + 3 * s
    t, u, v, w = y0, y0 + s, y0 + 2 * s, y0 + 3 * s
    outline = [(b, t), (c3, t), (c3, u), (d, u), (d, v), (c3, v), (c3, w), (b, w), (b, v),
               (a, v), (a, u), (b, u), (b, t)]  # fmt: skip
    tab_edges = {((c3, u), (d, u)), ((d, v), (c3, v)), ((b, v), (a, v)), ((a, u), (b, u))}
    for p, q in itertools.pairwise(outline):
        if (p, q) not in tab_edges:
            sheet.lines.append(Line(*p, *q))
    # Tabs on the ±x faces' edges that meet the ±y faces (they glue under them).
    for tab_x0, tab_x1 in ((c3, d), (a, b)):
        sheet.lines.extend(_tab(tab_x0, u, tab_x1, u, (0.0, -1.0)))
        sheet.lines.extend(_tab(tab_x0, v, tab_x1, v, (0.0, 1.0)))
    for p, q in (((b, u), (c3, u)), ((c3, u), (c3, v)), ((c3, v), (b, v)), ((b, v), (b, u))):
        sheet.lines.append(Line(*p, *q, dashed=True))
    # Sizes, ids, instructions and a scale bar to check the print.
    ids = ", ".join(f"{name} {i}" for name, i in zip(FACE_NAMES, cube.face_ids, strict=True))
    x = MARGIN_MM
    lines = [
        (14.0, "sim2real marker cube"),
        (10.0, f"Cube side {s:.1f} mm; marker (black square) {cube.marker_m * 1000:.1f} mm; "
               f"{cube.dictionary}"),
        (10.0, f"Face ids: {ids} (top = centre square)"),
        (9.0, "Print at 100 % / actual size (not 'fit to page'). The bar below must measure "
              f"{SCALE_BAR_MM:.0f} mm."),
        (9.0, "Cut along solid lines, fold along dashed lines, printed side out; glue the tabs"),
        (9.0, "under the neighbouring faces, or glue the five squares onto a wooden cube."),
        (9.0, "Keep the white margins clean: ArUco needs them to find the markers."),
    ]  # fmt: skip
    y = MARGIN_MM + 8.0
    for size, text in lines:
        sheet.texts.append(Text(x, y, size, text))
        y += size * 0.6
    bar_y = y + 6.0
    sheet.lines.append(Line(x, bar_y, x + SCALE_BAR_MM, bar_y, width_mm=0.4))
    for end in (x, x + SCALE_BAR_MM):
        sheet.lines.append(Line(end, bar_y - 2.0, end, bar_y + 2.0, width_mm=0.4))
    sheet.texts.append(Text(x + SCALE_BAR_MM + 3.0, bar_y + 1.2, 9.0, f"{SCALE_BAR_MM:.0f} mm"))
    return sheet


# ----------------------------------------------------------------------------- writers
def _pdf_text(text: str) -> str:
    ascii_text = text.encode("ascii", "replace").decode("ascii")
    return ascii_text.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)")


def sheet_pdf(sheet: Sheet) -> bytes:
    """A one-page vector PDF (PDF 1.4, Helvetica), page size in points from millimetres."""
    width, height = sheet.page_mm

    def pt(v: float) -> str:
        return f"{v * PT_PER_MM:.3f}"

    ops = ["0 g 0 G 1 J"]
    for box in sheet.boxes:
        y = height - box.y_mm - box.h_mm
        ops.append(f"{pt(box.x_mm)} {pt(y)} {pt(box.w_mm)} {pt(box.h_mm)} re f")
    for line in sheet.lines:
        dash = "[2 2] 0 d" if line.dashed else "[] 0 d"
        ops.append(
            f"{pt(line.width_mm)} w {dash} {pt(line.x0_mm)} {pt(height - line.y0_mm)} m "
            f"{pt(line.x1_mm)} {pt(height - line.y1_mm)} l S"
        )
    for text in sheet.texts:
        ops.append(
            f"BT /F1 {text.size_pt:.1f} Tf {pt(text.x_mm)} {pt(height - text.y_mm)} Td "
            f"({_pdf_text(text.text)}) Tj ET"
        )
    content = zlib.compress("\n".join(ops).encode("ascii"))
    objects = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {pt(width)} {pt(height)}] "
        "/Resources << /Font << /F1 5 0 R >> >> /Contents 4 0 R >>".encode("ascii"),
        f"<< /Length {len(content)} /Filter /FlateDecode >>\nstream\n".encode("ascii")
        + content
        + b"\nendstream",
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>",
    ]
    out = bytearray(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for i, body in enumerate(objects, start=1):
        offsets.append(len(out))
        out += f"{i} 0 obj\n".encode("ascii") + body + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objects) + 1}\n0000000000 65535 f \n".encode("ascii")
    out += b"".join(f"{o:010d} 00000 n \n".encode("ascii") for o in offsets)
    out += (
        f"trailer\n<< /Size {len(objects) + 1} /Root 1 0 R >>\nstartxref\n{xref}\n%%EOF\n"
    ).encode("ascii")
    return bytes(out)


def sheet_image(sheet: Sheet, dpi: float) -> np.ndarray:
    """The page as a grayscale uint8 image at ``dpi``."""
    if not (50.0 <= dpi <= 1200.0):
        raise ConfigError(f"dpi must be in [50, 1200], got {dpi}")
    k = dpi / MM_PER_INCH  # px per mm
    width, height = sheet.page_mm
    img = np.full((round(height * k), round(width * k)), 255, np.uint8)
    for box in sheet.boxes:
        x0, y0 = round(box.x_mm * k), round(box.y_mm * k)
        x1, y1 = round((box.x_mm + box.w_mm) * k), round((box.y_mm + box.h_mm) * k)
        img[y0:y1, x0:x1] = 0
    for line in sheet.lines:
        thickness = max(1, round(line.width_mm * k))
        p0 = np.array([line.x0_mm, line.y0_mm])
        p1 = np.array([line.x1_mm, line.y1_mm])
        length = float(np.linalg.norm(p1 - p0))
        pieces = (
            [(i / length, min((i + 1.0) / length, 1.0)) for i in np.arange(0.0, length, 2.0)]
            if line.dashed and length > 0
            else [(0.0, 1.0)]
        )  # 1 mm on, 1 mm off
        for f0, f1 in pieces:
            a = np.round((p0 + f0 * (p1 - p0)) * k).astype(int)
            b = np.round((p0 + f1 * (p1 - p0)) * k).astype(int)
            cv2.line(
                img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), (0,), thickness, cv2.LINE_AA
            )
    for text in sheet.texts:
        cap_px = text.size_pt / 72.0 * dpi * 0.7  # a font's cap height is ~0.7 of its size
        scale = cap_px / 22.0  # Hershey simplex: caps are ~22 px tall at scale 1
        org = (round(text.x_mm * k), round(text.y_mm * k))
        cv2.putText(img, text.text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0,),
                    max(1, round(scale * 1.5)), cv2.LINE_AA)  # fmt: skip
    return img


def sheet_png(sheet: Sheet, dpi: float) -> bytes:
    """PNG bytes with a ``pHYs`` chunk, so the image prints at true size at ``dpi``."""
    ok, buf = cv2.imencode(".png", sheet_image(sheet, dpi))
    if not ok:
        raise ConfigError("OpenCV could not encode the sheet as PNG")
    png = buf.tobytes()
    ppm = round(dpi / (MM_PER_INCH / 1000.0))
    data = ppm.to_bytes(4, "big") * 2 + b"\x01"  # pixels per metre, x and y; unit: metre
    chunk = (
        len(data).to_bytes(4, "big")
        + b"pHYs"
        + data
        + zlib.crc32(b"pHYs" + data).to_bytes(4, "big")
    )
    ihdr_end = 8 + 4 + 4 + 13 + 4  # signature, then IHDR's length, type, data and CRC
    return png[:ihdr_end] + chunk + png[ihdr_end:]
