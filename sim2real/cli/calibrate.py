"""``sim2real calibrate``: camera intrinsics, stereo, checks and camera-to-arm registration.

Subcommands::

    intrinsics  --images DIR | --live --cameras 0       one camera
    stereo      --left DIR --right DIR | --live --cameras 0,1
    check       --calib stereo.yaml --left DIR --right DIR   measure a known board
    register    --points CSV | --rig stereo.yaml --left DIR --right DIR --targets CSV
    cube-sheet  --out cube.pdf | cube.png [--dpi 300]   the marker cube's printable net

Every result is computed in memory first and then written file by file atomically under
``--out``, so a failed run never leaves a partial calibration behind. ``--json`` prints the
summary as one JSON document on stdout (warnings still go to stderr).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from calibration.errors import CalibrationError, ConfigError

if TYPE_CHECKING:  # the modules themselves load lazily: `sim2real --help` stays cv2-free
    import numpy as np

    from calibration.boards import BoardSpec
    from calibration.intrinsics import CalibrationConfig, IntrinsicsResult
    from calibration.stereo import StereoPair, StereoResult

_BOARD_HELP = (
    "chessboard:COLSxROWS:SQUARE (inner corners, square size in m) or "
    "charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy|:new] (squares)"
)


# ----------------------------------------------------------------------------- helpers
def _json_safe(value: Any) -> Any:
    """NaN/inf are not JSON: write them as null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def _dumps(summary: dict[str, Any]) -> str:
    return json.dumps(_json_safe(summary), indent=2, allow_nan=False)


def _warn(messages: list[str] | tuple[str, ...]) -> None:
    for message in messages:
        print(f"warning: {message}", file=sys.stderr)


def _emit(args: argparse.Namespace, summary: dict[str, Any], human: list[str]) -> None:
    print(_dumps(summary) if args.json else "\n".join(human))


def _config(args: argparse.Namespace) -> CalibrationConfig:
    from calibration.intrinsics import CalibrationConfig

    return CalibrationConfig(dist_model=args.model, reject_outliers=not args.no_reject)


def _cameras(text: str, count: int) -> list[int | str]:
    from calibration.capture import parse_source

    sources = [parse_source(s) for s in text.split(",") if s.strip()]
    if len(sources) != count:
        raise ConfigError(
            f"--cameras {text!r}: expected {count} source(s) separated by commas, got "
            f"{len(sources)}"
        )
    return sources


def _live(args: argparse.Namespace, names: list[str], board: BoardSpec) -> list[Path]:
    """Capture from cv2.VideoCapture sources into OUT/frames/<name>/ and return the folders."""
    from calibration.capture import OpenCVCamera
    from calibration.live import LiveConfig, capture_views

    if not args.cameras:
        raise ConfigError("--live needs --cameras (e.g. --cameras 0 or --cameras 0,1)")
    sources = _cameras(args.cameras, len(names))
    cameras: list[OpenCVCamera] = []
    try:
        for source in sources:
            cameras.append(OpenCVCamera(source, args.width, args.height))
        config = LiveConfig(target_views=args.views, max_frames=args.max_frames)
        return capture_views(
            cameras, names, board, Path(args.out), config,
            log=lambda line: print(line, file=sys.stderr),
        )  # fmt: skip
    finally:
        for cam in cameras:
            cam.close()


def _write_all(files: dict[Path, bytes | str]) -> list[str]:
    from s2r_common.atomic import atomic_write_bytes, atomic_write_text

    written = []
    for path, content in files.items():
        if isinstance(content, bytes):
            atomic_write_bytes(path, content)
        else:
            atomic_write_text(path, content)
        written.append(str(path))
    return written


def _report_files(
    out: Path, result: IntrinsicsResult | StereoResult, board: str
) -> dict[Path, bytes | str]:
    from calibration.report import PNG_NAME, markdown_report, render_png

    png = render_png(result)
    files: dict[Path, bytes | str] = {
        out / "report.md": markdown_report(result, board, png is not None)
    }
    if png is not None:
        files[out / PNG_NAME] = png
    else:
        _warn(["matplotlib is not installed: report.png skipped (report.md written)"])
    return files


def _stereo_pairs(
    board: BoardSpec, left: str, right: str
) -> tuple[list[StereoPair], tuple[int, int]]:
    from calibration.dataset import detect_images, list_images, pair_images
    from calibration.errors import ImageError
    from calibration.stereo import StereoPair

    pairs = pair_images(list_images(left), list_images(right))
    det_l = detect_images(board, [p[1] for p in pairs])
    det_r = detect_images(board, [p[2] for p in pairs])
    if det_l.image_size != det_r.image_size:
        raise ImageError(
            f"left images are {det_l.image_size[0]}x{det_l.image_size[1]} but right images "
            f"are {det_r.image_size[0]}x{det_r.image_size[1]}"
        )
    stereo = [
        StereoPair(key, dl, dr)
        for (key, _, _), dl, dr in zip(pairs, det_l.detections, det_r.detections, strict=True)
    ]
    return stereo, det_l.image_size


# ----------------------------------------------------------------------------- intrinsics
def _run_intrinsics(args: argparse.Namespace) -> int:
    from calibration.boards import parse_board
    from calibration.dataset import detect_images, list_images
    from calibration.intrinsics import View, calibrate_camera

    board = parse_board(args.board)
    config = _config(args)
    out = Path(args.out)
    source = _live(args, [args.name], board)[0] if args.live else args.images
    if source is None:
        raise ConfigError("give --images DIR (or --live --cameras N)")
    paths = list_images(source)
    detected = detect_images(board, paths)
    views = [View(p.name, d) for p, d in zip(paths, detected.detections, strict=True) if d]
    failed = [p.name for p, d in zip(paths, detected.detections, strict=True) if d is None]
    result = calibrate_camera(views, detected.image_size, config, name=args.name, failed=failed)

    summary = result.summary()
    summary["board"] = str(board)
    files: dict[Path, bytes | str] = {
        out / "camera.yaml": _camera_yaml(result),
        out / "camera_info.yaml": result.camera.ros_yaml(),
    }
    files.update(_report_files(out, result, str(board)))
    summary["outputs"] = [str(p) for p in files] + [str(out / "summary.json")]
    files[out / "summary.json"] = _dumps(summary) + "\n"
    _write_all(files)
    _warn(result.warnings)
    cam = result.camera
    _emit(
        args,
        summary,
        [
            f"{cam.name}: fx {cam.fx:.2f} fy {cam.fy:.2f} cx {cam.cx:.2f} cy {cam.cy:.2f} px; "
            f"RMS {result.rms_px:.3f} px; views used {result.views_used}, rejected "
            f"{result.views_rejected}",
            f"wrote {', '.join(str(p) for p in files)}",
        ],
    )
    return 0


def _camera_yaml(result: IntrinsicsResult) -> str:
    from calibration.camera import fs_dumps

    entries = dict(result.camera.fs_entries())
    entries.update(result.fs_extra())
    return fs_dumps(entries)


# ----------------------------------------------------------------------------- stereo
def _run_stereo(args: argparse.Namespace) -> int:
    from calibration.boards import parse_board
    from calibration.camera import fs_dumps
    from calibration.stereo import calibrate_stereo

    board = parse_board(args.board)
    config = _config(args)
    names = [n.strip() for n in args.names.split(",")]
    if len(names) != 2 or not all(names) or names[0] == names[1]:
        raise ConfigError(f"--names {args.names!r}: expected two different names like left,right")
    out = Path(args.out)
    if args.live:
        left_dir, right_dir = (str(p) for p in _live(args, names, board))
    elif args.left and args.right:
        left_dir, right_dir = args.left, args.right
    else:
        raise ConfigError("give --left DIR and --right DIR (or --live --cameras A,B)")
    pairs, size = _stereo_pairs(board, left_dir, right_dir)
    result = calibrate_stereo(
        pairs, board, size, config, refine_intrinsics=args.refine_intrinsics,
        names=(names[0], names[1]),
    )  # fmt: skip
    rig, rect = result.rig, result.rig.rectification
    summary = result.summary()
    summary["board"] = str(board)
    left_yaml = dict(rig.left.fs_entries())
    left_yaml.update(result.left.fs_extra())
    right_yaml = dict(rig.right.fs_entries())
    right_yaml.update(result.right.fs_extra())
    files: dict[Path, bytes | str] = {
        out / "stereo.yaml": fs_dumps({**rig.fs_entries(), **result.fs_extra()}),
        out / f"{names[0]}.yaml": fs_dumps(left_yaml),
        out / f"{names[1]}.yaml": fs_dumps(right_yaml),
        out / f"{names[0]}_camera_info.yaml": rig.left.ros_yaml(rect.R1, rect.P1),
        out / f"{names[1]}_camera_info.yaml": rig.right.ros_yaml(rect.R2, rect.P2),
    }
    files.update(_report_files(out, result, str(board)))
    summary["outputs"] = [str(p) for p in files] + [str(out / "summary.json")]
    files[out / "summary.json"] = _dumps(summary) + "\n"
    _write_all(files)
    _warn(result.all_warnings)
    _emit(
        args,
        summary,
        [
            f"stereo RMS {result.rms_px:.3f} px over {result.views_used} pairs "
            f"({result.views_rejected} rejected); baseline {rig.baseline:.5g} (board units); "
            f"epipolar RMS {result.epipolar_rms_px:.3f} px",
            *(
                f"{r.camera.name}: fx {r.camera.fx:.2f} fy {r.camera.fy:.2f} cx "
                f"{r.camera.cx:.2f} cy {r.camera.cy:.2f} px; RMS {r.rms_px:.3f} px"
                for r in (result.left, result.right)
            ),
            f"wrote {', '.join(str(p) for p in files)}",
        ],
    )
    return 0


# ----------------------------------------------------------------------------- check
def _run_check(args: argparse.Namespace) -> int:
    from calibration.boards import parse_board
    from calibration.check import check_stereo
    from calibration.triangulate import StereoRig

    board = parse_board(args.board)
    rig = StereoRig.load(args.calib)
    pairs, size = _stereo_pairs(board, args.left, args.right)
    if size != rig.left.image_size:
        raise ConfigError(
            f"the images are {size[0]}x{size[1]} but {args.calib} was calibrated at "
            f"{rig.left.image_size[0]}x{rig.left.image_size[1]}"
        )
    result = check_stereo(rig, pairs, board)
    passed = (
        abs(result.square_size_error_pct) <= args.max_error_pct
        and result.epipolar_rms_px <= args.max_epipolar_px
    )
    summary = result.summary()
    summary.update(
        passed=passed, max_error_pct=args.max_error_pct, max_epipolar_px=args.max_epipolar_px
    )
    _emit(
        args,
        summary,
        [
            f"square size {result.square_size:.5g} vs {result.square_size_expected:.5g}: "
            f"error {result.square_size_error_pct:+.2f}% (spread {result.square_size_spread_pct:.2f}%)",
            f"epipolar error RMS {result.epipolar_rms_px:.3f} px, max "
            f"{result.epipolar_max_px:.3f} px over {len(result.pairs)} pairs",
            "PASS" if passed else "FAIL",
        ],
    )
    return 0 if passed else 1


# ----------------------------------------------------------------------------- register
def _run_register(args: argparse.Namespace) -> int:
    from calibration.registration import read_correspondences, register

    if args.points:
        names, cam_p, base_p = read_correspondences(args.points)
        skipped: list[str] = []
    elif args.rig and args.left and args.right and args.targets:
        names, cam_p, base_p, skipped = _marker_correspondences(args)
    else:
        raise ConfigError("give --points CSV, or --rig FILE --left DIR --right DIR --targets CSV")
    reg = register(cam_p, base_p, names)
    out = Path(args.out)
    summary = reg.summary()
    summary["skipped"] = skipped
    warnings = []
    if reg.rms_m > args.warn_rms_m:
        worst = names[int(reg.residuals_m.argmax())]
        warnings.append(
            f"registration RMS {1000 * reg.rms_m:.1f} mm is above {1000 * args.warn_rms_m:.1f} mm"
            f" (worst point {worst!r}: {1000 * reg.max_m:.1f} mm)"
        )
    summary["warnings"] = warnings
    reg.save(out / "base_T_cam.yaml")
    files: dict[Path, bytes | str] = {out / "registration.json": _dumps(summary) + "\n"}
    _write_all(files)
    _warn(warnings)
    _emit(
        args,
        summary,
        [
            f"base_T_cam from {len(names)} points: RMS {1000 * reg.rms_m:.2f} mm, max "
            f"{1000 * reg.max_m:.2f} mm",
            *(f"  {n}: {1000 * r:.2f} mm" for n, r in zip(names, reg.residuals_m, strict=True)),
            f"wrote {out / 'base_T_cam.yaml'}, {out / 'registration.json'}",
        ],
    )
    return 0


# ----------------------------------------------------------------------------- cube-sheet
def _run_cube_sheet(args: argparse.Namespace) -> int:
    from calibration.cube import FACE_NAMES, MarkerCube
    from calibration.cube_sheet import cube_sheet, sheet_pdf, sheet_png

    out = Path(args.out)
    writers: dict[str, Callable[[Any], bytes]] = {
        ".pdf": sheet_pdf,
        ".png": lambda sheet: sheet_png(sheet, args.dpi),
    }
    if out.suffix.lower() not in writers:
        raise ConfigError(f"--out {args.out!r}: the sheet is written as .pdf or .png")
    try:
        ids = tuple(int(i) for i in args.ids.split(","))
    except ValueError:
        raise ConfigError(f"--ids {args.ids!r}: give five integers separated by commas") from None
    cube = MarkerCube(args.size_m, args.marker_m, ids, args.dictionary)
    sheet = cube_sheet(cube, args.page)
    _write_all({out: writers[out.suffix.lower()](sheet)})
    summary = {
        "out": str(out),
        "cube_side_m": cube.size_m,
        "marker_side_m": cube.marker_m,
        "dictionary": cube.dictionary,
        "face_ids": dict(zip(FACE_NAMES, cube.face_ids, strict=True)),
        "page": args.page,
        "dpi": args.dpi if out.suffix.lower() == ".png" else None,
    }
    _emit(
        args,
        summary,
        [
            f"wrote {out}: cube side {1000 * cube.size_m:.1f} mm, markers "
            f"{1000 * cube.marker_m:.1f} mm, {cube.dictionary} ids {list(cube.face_ids)} "
            "(top, +x, -x, +y, -y); print at 100 %",
        ],
    )
    return 0


def _marker_correspondences(
    args: argparse.Namespace,
) -> tuple[list[str], np.ndarray, np.ndarray, list[str]]:
    """Triangulate the marker centre in every image pair and match it to the arm's targets."""
    import numpy as np

    from calibration.dataset import list_images, pair_images, read_gray
    from calibration.markers import ArucoMarkerDetector
    from calibration.registration import read_targets
    from calibration.triangulate import StereoRig

    rig = StereoRig.load(args.rig)
    targets = read_targets(args.targets)
    detector = ArucoMarkerDetector(args.dictionary)
    names: list[str] = []
    cam_p: list[np.ndarray] = []
    base_p: list[np.ndarray] = []
    skipped: list[str] = []
    for key, left_path, right_path in pair_images(list_images(args.left), list_images(args.right)):
        target = next(
            (targets[k] for k in (key, left_path.name, left_path.stem) if k in targets), None
        )
        if target is None:
            skipped.append(f"{key}: no target in {args.targets}")
            continue
        left = detector.find(read_gray(left_path), args.marker_id)
        right = detector.find(read_gray(right_path), args.marker_id)
        if left is None or right is None:
            skipped.append(f"{key}: marker {args.marker_id} not found in both images")
            continue
        corners = rig.triangulate(left.corners_px, right.corners_px)
        names.append(key)
        cam_p.append(corners.mean(axis=0))
        base_p.append(target)
    return names, np.array(cam_p).reshape(-1, 3), np.array(base_p).reshape(-1, 3), skipped


# ----------------------------------------------------------------------------- argparse
def _calibration_options(p: argparse.ArgumentParser) -> None:
    from calibration.intrinsics import DIST_MODELS

    p.add_argument("--board", required=True, help=_BOARD_HELP)
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    p.add_argument("--model", default="plumb_bob", choices=sorted(DIST_MODELS),
                   help="distortion model (default: plumb_bob = k1 k2 p1 p2 k3)")  # fmt: skip
    p.add_argument("--no-reject", action="store_true", help="keep outlier views")
    p.add_argument("--live", action="store_true", help="capture from cv2.VideoCapture sources")
    p.add_argument("--cameras", help="live sources: device indices, files or URLs, comma-separated")
    p.add_argument("--views", type=int, default=20, help="live: views to accept (default 20)")
    p.add_argument("--max-frames", type=int, default=3000, help="live: frames to read at most")
    p.add_argument("--width", type=int, help="live: requested frame width (px)")
    p.add_argument("--height", type=int, help="live: requested frame height (px)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="calibrate_command", metavar="SUBCOMMAND", required=True)

    p = sub.add_parser("intrinsics", help="calibrate one camera from board images")
    p.add_argument("--images", help="folder of images (or a glob pattern)")
    p.add_argument("--name", default="camera", help="camera name in the outputs")
    _calibration_options(p)
    p.set_defaults(_calibrate=_run_intrinsics)

    p = sub.add_parser("stereo", help="calibrate a stereo pair from board image pairs")
    p.add_argument("--left", help="left images: folder or glob (paired with --right by name)")
    p.add_argument("--right", help="right images: folder or glob")
    p.add_argument("--names", default="left,right", help="camera names (default left,right)")
    p.add_argument("--refine-intrinsics", action="store_true",
                   help="let stereoCalibrate refine K and dist (default: held fixed)")  # fmt: skip
    _calibration_options(p)
    p.set_defaults(_calibrate=_run_stereo)

    p = sub.add_parser("check", help="measure a known board with an existing stereo calibration")
    p.add_argument("--calib", required=True, help="stereo.yaml written by 'calibrate stereo'")
    p.add_argument("--left", required=True, help="left images: folder or glob")
    p.add_argument("--right", required=True, help="right images: folder or glob")
    p.add_argument("--board", required=True, help=_BOARD_HELP)
    p.add_argument("--max-error-pct", type=float, default=1.0,
                   help="square size error allowed to pass (default 1%%)")  # fmt: skip
    p.add_argument("--max-epipolar-px", type=float, default=0.5,
                   help="epipolar RMS allowed to pass (default 0.5 px)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.set_defaults(_calibrate=_run_check)

    p = sub.add_parser("register", help="fit base_T_cam from marker positions the arm visited")
    p.add_argument("--points", help="CSV name,cam_x,cam_y,cam_z,base_x,base_y,base_z (m)")
    p.add_argument("--rig", help="stereo.yaml, to triangulate the marker in --left/--right")
    p.add_argument("--left", help="left images: folder or glob")
    p.add_argument("--right", help="right images: folder or glob")
    p.add_argument("--targets", help="CSV name,base_x,base_y,base_z: marker positions (m)")
    p.add_argument("--marker-id", type=int, default=0, help="ArUco id on the arm (default 0)")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="ArUco dictionary")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--warn-rms-m", type=float, default=0.005,
                   help="warn above this residual RMS (default 0.005 m)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.set_defaults(_calibrate=_run_register)

    p = sub.add_parser("cube-sheet", help="print the marker cube's net (PDF, or PNG at --dpi)")
    p.add_argument("--out", required=True, help="cube.pdf (vector) or cube.png")
    p.add_argument("--dpi", type=float, default=300.0, help="PNG resolution (default 300)")
    p.add_argument("--page", default="a4", choices=("a4", "letter"), help="paper (default a4)")
    p.add_argument("--size-m", type=float, default=0.025, help="cube side (default 0.025 m)")
    p.add_argument("--marker-m", type=float, default=0.02,
                   help="marker black square side (default 0.02 m)")  # fmt: skip
    p.add_argument("--ids", default="2,3,4,5,6", help="face ids: top,+x,-x,+y,-y (default 2-6)")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="ArUco dictionary")
    p.add_argument("--json", action="store_true", help="print the sizes as JSON on stdout")
    p.set_defaults(_calibrate=_run_cube_sheet)


def run(args: argparse.Namespace) -> int:
    handler: Callable[[argparse.Namespace], int] = args._calibrate
    try:
        return handler(args)
    except CalibrationError:
        raise
    except OSError as exc:  # e.g. --out on a read-only disk: still one line, not a traceback
        raise CalibrationError(f"{exc.strerror or exc}: {exc.filename or ''}".strip(": ")) from exc
