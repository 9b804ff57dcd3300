"""How one run is drawn in Rerun: entity paths, styles, and the per-period pieces shared by the
recorder (``record``: a finished run) and the live stream (``live``: a running deploy).

Everything of a run lives under ``/<label>``, so two runs sit side by side in one recording::

    /<label>/world                        3D, the arm's base frame (z up, metres)
        arm/reading  arm/command  arm/sent    the arm from its readings; the policy's command and
                                              what the safety filter sent, as ghosts
        estimates/<tool|object>             tracked positions (covariance ellipsoids where logged)
        truth/<tool|object>                 the simulator's truth (sim, mock)
        cameras/<left|right>                pinhole + image, detected markers, reprojected estimates
    /<label>/joints/<joint>/command|sent|reading      rad
    /<label>/gripper/holding   /<label>/objects/<name>/blind_s   /<label>/distance/<estimate|truth>_m
    /<label>/timing/period_s|wake_late_s|<section>_s  /<label>/outcome/reward|success|episode_success|episode
    /<label>/events/overrun   /<label>/events/safety/<rule>   /<label>/events/log

Timelines: ``period`` (the run's period index from its start: two runs line up period for
period) and ``time`` (seconds from the run's first period); the episode number is a series
(``outcome/episode``), not a timeline, so that the viewer opens on ``period``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import rerun as rr

from hardware.spec import ArmSpec
from sim2real.view.scene import MarkerFinder, ViewCamera, arm_points_m
from sim2real.view.signals import SAFETY_EVENTS as SAFETY_RULES

SECTIONS = ("read", "perceive", "infer", "command")
GHOSTS: dict[str, tuple[str, tuple[int, int, int, int]]] = {
    # entity -> (log column, RGBA): the reading solid, the command and the sent pose as ghosts
    "reading": ("joints_rad", (60, 140, 255, 255)),
    "command": ("targets_rad", (255, 160, 40, 110)),
    "sent": ("sent_rad", (80, 220, 120, 110)),
}
PALETTE: tuple[tuple[int, int, int], ...] = (
    (255, 80, 80), (250, 200, 40), (170, 110, 255), (40, 220, 220), (255, 120, 200),
)  # fmt: skip
TOOL_RGB = (60, 140, 255)
TRUTH_RGB = (230, 230, 230)
EVENT_RGB = (255, 60, 60)
MARKER_RGB = (0, 255, 0)


def object_rgb(objects: Sequence[str], name: str) -> tuple[int, int, int]:
    return TOOL_RGB if name == "tool" else PALETTE[list(objects).index(name) % len(PALETTE)]


def series(
    columns: Mapping[str, np.ndarray], joint_names: Sequence[str], objects: Sequence[str]
) -> dict[str, np.ndarray]:
    """Entity subpath -> (n,) values of every scalar series the columns hold."""
    out: dict[str, np.ndarray] = {}
    for key, name in (("targets_rad", "command"), ("sent_rad", "sent"), ("joints_rad", "reading")):
        values = columns.get(key)
        if values is not None:
            for i, joint in enumerate(joint_names[: values.shape[1]]):
                out[f"joints/{joint}/{name}"] = values[:, i]
    scalars = {
        "grasped": "gripper/holding",
        "ee_seen": "tracking/tool_seen",
        "period_s": "timing/period_s",
        "wake_late_s": "timing/wake_late_s",
        "reward": "outcome/reward",
        "success": "outcome/success",
        "episode": "outcome/episode",
        **{f"{s}_s": f"timing/{s}_s" for s in SECTIONS},
        **{f"{o}_blind_s": f"objects/{o}/blind_s" for o in objects},
    }
    for key, path in scalars.items():
        if key in columns:
            out[path] = np.asarray(columns[key], dtype=float).reshape(-1)
    if objects:
        pairs = {"estimate": ("ee_est_m", f"{objects[0]}_est_m"),
                 "truth": ("true_tool_m", f"{objects[0]}_true_m")}  # fmt: skip
        for name, (tool, obj) in pairs.items():
            if tool in columns and obj in columns:
                out[f"distance/{name}_m"] = np.linalg.norm(columns[tool] - columns[obj], axis=1)
    return out


def points(row: Mapping[str, Any], objects: Sequence[str]) -> dict[str, dict[str, np.ndarray]]:
    """``{"estimates": {name: (3,)}, "truth": {...}}`` of one period, finite points only."""
    keys = {
        "estimates": {"tool": "ee_est_m", **{o: f"{o}_est_m" for o in objects}},
        "truth": {"tool": "true_tool_m", **{o: f"{o}_true_m" for o in objects}},
    }
    out: dict[str, dict[str, np.ndarray]] = {}
    for group, names in keys.items():
        for name, key in names.items():
            value = row.get(key)
            if value is None:
                continue
            p = np.asarray(value, dtype=float).reshape(-1)
            if p.shape == (3,) and np.all(np.isfinite(p)):
                out.setdefault(group, {})[name] = p
    return out


class RunDrawer:
    """Draws one run's pieces under ``/<label>`` on a recording stream."""

    def __init__(
        self,
        rec: rr.RecordingStream,
        label: str,
        spec: ArmSpec,
        objects: Sequence[str],
        cameras: tuple[ViewCamera, ViewCamera] | None = None,
    ) -> None:
        self.rec, self.root, self.spec = rec, f"/{label}", spec
        self.objects = tuple(objects)
        self.cameras = cameras
        self.joint_names = spec.actuator_names
        self._finder: MarkerFinder | None = None
        self._sized: dict[int, ViewCamera] = {}

    def path(self, sub: str) -> str:
        return f"{self.root}/{sub}"

    def _log(self, path: str, *what: Any, static: bool = False) -> None:
        rr.log(path, *what, static=static, recording=self.rec)

    # ---- static --------------------------------------------------------------------------
    def static(self, notes: Mapping[str, Any], image_wh: tuple[int, int] | None = None) -> None:
        self._log(self.path("world"), rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for joint in self.joint_names:
            for name, (_, rgba) in GHOSTS.items():
                self._log(self.path(f"joints/{joint}/{name}"),
                        rr.SeriesLine(name=f"{joint} {name}", color=rgba[:3]), static=True)  # fmt: skip
        for sub in ("events/overrun", *(f"events/safety/{k}" for k in SAFETY_RULES)):
            self._log(self.path(sub), rr.SeriesPoint(color=EVENT_RGB, marker="cross",
                                                   name=sub.rsplit("/", 1)[-1]), static=True)  # fmt: skip
        text = "\n".join(f"- **{k}**: {v}" for k, v in notes.items())
        self._log(self.path("about"), rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN),
                static=True)  # fmt: skip
        if self.cameras is not None:
            for side, cam in zip(("left", "right"), self.cameras, strict=True):
                cam = cam.scaled(image_wh) if image_wh is not None else cam
                T = cam.base_T_cam
                base = self.path(f"world/cameras/{side}")
                self._log(base, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
                self._log(base, rr.Pinhole(image_from_camera=cam.K, resolution=list(cam.size_wh),
                                         camera_xyz=rr.ViewCoordinates.RDF), static=True)  # fmt: skip

    # ---- one period ----------------------------------------------------------------------
    def set_time(self, period: int, time_s: float) -> None:
        rr.set_time_sequence("period", period, recording=self.rec)
        rr.set_time_seconds("time", time_s, recording=self.rec)

    def scene(self, row: Mapping[str, Any]) -> None:
        """The 3D view of one period: the arm, its ghosts, estimates and truth."""
        for name, (key, rgba) in GHOSTS.items():
            q = row.get(key)
            if q is None:
                continue
            strip = arm_points_m(self.spec, np.asarray(q, dtype=float))
            if np.all(np.isfinite(strip)):
                radius = 0.006 if name == "reading" else 0.004
                self._log(self.path(f"world/arm/{name}"),
                        rr.LineStrips3D([strip], colors=[rgba], radii=radius))  # fmt: skip
        for group, found in points(row, self.objects).items():
            for name, p in found.items():
                rgb = TRUTH_RGB if group == "truth" else object_rgb(self.objects, name)
                self._log(self.path(f"world/{group}/{name}"),
                        rr.Points3D([p], colors=[rgb], radii=0.006 if group == "truth" else 0.008,
                                    labels=[name if group == "estimates" else f"{name} (truth)"]))  # fmt: skip
                cov = row.get(f"{name}_cov_m2") if group == "estimates" else None
                if cov is not None:
                    self._ellipsoid(name, p, np.asarray(cov, dtype=float))

    def _ellipsoid(self, name: str, centre_m: np.ndarray, cov: np.ndarray) -> None:
        """A 2-sigma ellipsoid of a (3, 3) covariance (m^2), where a tracker logged one."""
        if cov.size != 9 or not np.all(np.isfinite(cov)):
            return
        values, vectors = np.linalg.eigh(cov.reshape(3, 3))
        if np.linalg.det(vectors) < 0:
            vectors[:, 0] *= -1
        from calibration.triangulate import quaternion_from_matrix

        w, x, y, z = quaternion_from_matrix(vectors)
        self._log(self.path(f"world/estimates/{name}/covariance"),
                     rr.Ellipsoids3D(centers=[centre_m], half_sizes=[2 * np.sqrt(np.maximum(values, 0))],
                                     quaternions=[rr.Quaternion(xyzw=[x, y, z, w])],
                                     colors=[object_rgb(self.objects, name)]))  # fmt: skip

    def frames(self, pair: tuple[np.ndarray, np.ndarray], row: Mapping[str, Any]) -> int:
        """Both cameras' frames with the markers found in them and the period's estimates (and
        truth) projected back in; returns how many markers were found."""
        if self._finder is None:
            self._finder = MarkerFinder()
        found = points(row, self.objects)
        n = 0
        for side, rgb in zip(("left", "right"), pair, strict=True):
            base = self.path(f"world/cameras/{side}")
            self._log(f"{base}/image", rr.Image(rgb).compress(jpeg_quality=80))
            markers = self._finder.find(rgb)
            n += len(markers)
            self._log(f"{base}/markers", rr.LineStrips2D(
                [np.vstack([m.corners_px, m.corners_px[:1]]) for m in markers],
                labels=[m.label for m in markers], colors=[MARKER_RGB] * len(markers)))  # fmt: skip
            if self.cameras is None:
                continue
            cam = self._camera(side, rgb.shape)
            labels, uv, colors = [], [], []
            for group, named in found.items():
                for name, p in named.items():
                    px = cam.project(p)[0]
                    if np.all(np.isfinite(px)):
                        labels.append(name if group == "estimates" else f"{name} (truth)")
                        uv.append(px)
                        colors.append(
                            TRUTH_RGB if group == "truth" else object_rgb(self.objects, name)
                        )
            self._log(f"{base}/reprojection",
                         rr.Points2D(uv, labels=labels, colors=colors, radii=3.0))  # fmt: skip
        return n

    def _camera(self, side: str, shape: tuple[int, ...]) -> ViewCamera:
        assert self.cameras is not None
        i = 0 if side == "left" else 1
        cam = self._sized.get(i)
        if cam is None or cam.size_wh != (shape[1], shape[0]):
            cam = self._sized[i] = self.cameras[i].scaled((shape[1], shape[0]))
        return cam

    def scalars(self, values: Mapping[str, float]) -> None:
        """One period's scalar series (live); the recorder sends whole columns instead."""
        for sub, v in values.items():
            if np.isfinite(v):
                self._log(self.path(sub), rr.Scalar(float(v)))

    def event(self, text: str, level: str = "WARN") -> None:
        self._log(self.path("events/log"), rr.TextLog(text, level=level))

    def send_series(
        self, sub: str, values: np.ndarray, period: np.ndarray, time_s: np.ndarray
    ) -> int:
        """A whole scalar column at once (NaN rows left out); returns the samples sent."""
        ok = np.isfinite(values)
        if not ok.any():
            return 0
        rr.send_columns(
            self.path(sub),
            indexes=[rr.TimeSequenceColumn("period", period[ok]),
                     rr.TimeSecondsColumn("time", time_s[ok])],
            columns=rr.Scalar.columns(scalar=values[ok]),
            recording=self.rec,
        )  # fmt: skip
        return int(ok.sum())
