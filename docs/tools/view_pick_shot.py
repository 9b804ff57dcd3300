"""Regenerate ``docs/img/view-mock-pick.png``: the viewer on a mock pick run, at a period where
the fingers hold the lifted cube, the cameras do not see it and its estimate is held.

1. A two-episode mock deploy of the shipped ``pick-ppo`` with its log and frames (skipped with
   ``--log`` and ``--frames`` to reuse a run).
2. The period: grasped, the cube (truth) lifted at least ``--lift-m`` off where it started, and
   blind (``cube_blind_s`` > 0, so the tracker holds its last sighting); of those, the longest
   blind. Its figures are printed.
3. The run, cut to end at that period (the viewer opens on the last period), written as an
   ``.rrd`` with ``sim2real.view`` (the recording ``sim2real view`` writes; the 3D view leaves the
   camera frusta out so that it frames the arm and the cube).
4. ``rerun --serve-web`` serves it; headless Chromium (SwiftShader's WebGPU on its Vulkan),
   driven over the DevTools protocol, loads the web viewer, zooms and turns the 3D view's camera
   with the mouse (``--zoom``, ``--orbit-x``) and takes the screenshot once the page has settled;
   PIL quantizes it to 256 colours.

    python docs/tools/view_pick_shot.py                    # deploy, then the picture
    python docs/tools/view_pick_shot.py --log L.npz --frames DIR --out shot.png

Needs the ``view`` and ``sim`` extras, Chromium (``--chromium``) and bash. The deploy runs in
real time: on a loaded machine it may stop on a stall or watchdog (try again; ``--watchdog-s`` is
passed).
This file is not part of the site (``exclude_docs`` in ``mkdocs.yml``).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import fcntl
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # sim2real.view needs the view extra: imported where used
    from sim2real.view.sources import ViewRun

REPO = Path(__file__).resolve().parents[2]
LABEL = "mock"
# Headless, software rendering: SwiftShader (WebGPU on its Vulkan, WebGL on ANGLE).
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--no-first-run", "--hide-scrollbars",
    "--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--enable-unsafe-webgpu",
    "--enable-features=Vulkan", "--use-vulkan=swiftshader", "--use-webgpu-adapter=swiftshader",
]  # fmt: skip


def deploy(out: Path, episodes: int, seed: int | None, watchdog_s: float) -> tuple[Path, Path]:
    log, frames = out / "pick.npz", out / "pick-frames"
    cmd = [sys.executable, "-m", "sim2real", "deploy", "pick-ppo", "--backend", "mock",
           "--episodes", str(episodes), "--watchdog-s", str(watchdog_s),
           "--log", str(log), "--record-dataset", str(frames)]  # fmt: skip
    if seed is not None:
        cmd += ["--seed", str(seed)]
    print("$", " ".join(cmd[1:]), flush=True)
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    subprocess.run(cmd, check=True, cwd=REPO, env=env)
    return log, frames


def pick_period(cols: dict[str, np.ndarray], lift_m: float) -> int:
    """The held-and-hidden period: grasped, lifted, blind; the longest blind of those."""
    z = cols["cube_true_m"][:, 2]
    episode = cols["episode"].astype(int)
    start_z = np.array([z[np.flatnonzero(episode == e)[0]] for e in episode])
    blind = cols["cube_blind_s"]
    ok = (cols["grasped"] > 0.5) & (z - start_z >= lift_m) & (blind > 0)
    if not ok.any():
        raise SystemExit("no period with the cube grasped, lifted and unseen: run again")
    return int(np.flatnonzero(ok)[np.argmax(blind[ok])])


def cut(run: ViewRun, last: int) -> ViewRun:
    """The run up to and including period ``last``; the cut episode's verdict unknown."""
    from sim2real.view.sources import EpisodeOutcome

    columns = {k: v[: last + 1] for k, v in run.columns.items()}
    episodes = []
    for ep in run.episodes:
        if ep.first_period > last:
            break
        if ep.first_period + ep.periods - 1 > last:
            n = last - ep.first_period + 1
            ep = EpisodeOutcome(
                ep.index, ep.first_period, n, None, f"recording cut at period {last}"
            )
        episodes.append(ep)
    return replace(run, columns=columns, episodes=tuple(episodes))


def write_rrd(run: ViewRun, path: Path) -> None:
    import rerun as rr
    import rerun.blueprint as rrb

    from hardware.spec import load_spec
    from sim2real.view.record import APPLICATION_ID, blueprint, log_run
    from sim2real.view.scene import mock_rig_cameras

    root = f"/{run.label}"
    cameras = mock_rig_cameras()
    # The layout ``sim2real view`` sends (``record.blueprint``), but the 3D view without the
    # camera frusta (they sit far above the table, and the view would frame them), the cameras
    # given more room.
    left = rrb.Vertical(
        rrb.Spatial3DView(origin=f"{root}/world", name=f"{run.label}: 3D",
                          contents=["$origin/**", "- $origin/cameras/**"]),
        rrb.Horizontal(*(
            rrb.Spatial2DView(origin=f"{root}/world/cameras/{side}", name=f"{side} camera")
            for side in ("left", "right")
        )),
        row_shares=[1.0, 1.0],
    )  # fmt: skip
    plots = blueprint([run.label], cameras=True).root_container.contents[1]  # as it is
    bp = rrb.Blueprint(
        rrb.Horizontal(left, plots, name=run.label),
        rrb.BlueprintPanel(expanded=False),
        rrb.SelectionPanel(expanded=False),
        rrb.TimePanel(expanded=True),
    )
    rec = rr.new_recording(APPLICATION_ID, recording_id=str(uuid.uuid4()))
    rec.save(str(path))
    rr.send_blueprint(bp, recording=rec)
    log_run(rec, run, load_spec(None), cameras)
    rec.flush(blocking=True)
    rr.disconnect(recording=rec)


def stop_group(proc: subprocess.Popen[bytes]) -> None:
    """End a child started in its own session, and what it started (``rerun`` is a launcher for
    the viewer's binary; Chromium starts its helpers)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Chromium:
    """Headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
    NUL-terminated JSON on fds 3 and 4), so nothing beyond the standard library is needed."""

    def __init__(self, exe: str, size: tuple[int, int], profile: Path) -> None:
        to_r, self._to = os.pipe()
        self._from, from_w = os.pipe()
        # The child's fd 3 reads our commands and its fd 4 writes the replies: the pipe's ends
        # moved above 9 first, so that the redirections cannot overwrite one another (bash: dash
        # takes one-digit fds only).
        child_r, child_w = (fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in (to_r, from_w))
        os.close(to_r)
        os.close(from_w)
        redirect = f'exec "$@" 3<&{child_r} 4>&{child_w} {child_r}<&- {child_w}>&-'
        self.proc = subprocess.Popen(
            ["bash", "-c", redirect, "bash", exe, *CHROMIUM_FLAGS, "--remote-debugging-pipe",
             f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}", "about:blank"],
            pass_fds=(child_r, child_w), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True,
        )  # fmt: skip
        to_r, from_w = child_r, child_w
        os.close(to_r)
        os.close(from_w)
        self._buf = b""
        self._id = 0
        page = next(t for t in self.call("Target.getTargets")["targetInfos"] if t["type"] == "page")
        self.session = self.call("Target.attachToTarget", targetId=page["targetId"],
                                 flatten=True)["sessionId"]  # fmt: skip

    def call(self, method: str, session: str | None = None, **params: object) -> dict:
        self._id += 1
        msg: dict[str, object] = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        os.write(self._to, json.dumps(msg).encode() + b"\0")
        while True:
            while b"\0" not in self._buf:
                chunk = os.read(self._from, 1 << 20)
                if not chunk:
                    raise RuntimeError(f"chromium closed the pipe during {method}")
                self._buf += chunk
            raw, self._buf = self._buf.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply["result"])

    def page(self, method: str, **params: object) -> dict:
        return self.call(method, self.session, **params)

    def close(self) -> None:
        with contextlib.suppress(RuntimeError, OSError):
            self.call("Browser.close")
        stop_group(self.proc)
        os.close(self._to)
        os.close(self._from)


def settle(browser: Chromium, min_s: float, max_s: float) -> bytes:
    """Capture the page every few seconds until two captures in a row differ in under 0.2 % of
    their pixels (after ``min_s`` at least, ``max_s`` at most); the last capture."""
    from PIL import Image, ImageChops

    start, last = time.monotonic(), None
    while True:
        time.sleep(4.0)
        shot = base64.b64decode(browser.page("Page.captureScreenshot")["data"])
        img = Image.open(io.BytesIO(shot)).convert("RGB")
        waited = time.monotonic() - start
        changed = 1.0
        if last is not None and last.size == img.size:
            diff = np.asarray(ImageChops.difference(img, last)).max(axis=2)
            changed = float(np.mean(diff > 8))
        print(f"  {waited:4.0f} s: {100 * changed:5.1f} % of the pixels changed", flush=True)
        if (waited >= min_s and changed < 0.002) or waited > max_s:
            return shot
        last = img


def mouse(browser: Chromium, x: float, y: float, zoom: float, orbit: tuple[float, float]) -> None:
    """In the 3D view at (x, y): ``zoom`` wheel steps of 20 px (positive: out), then a left
    drag of ``orbit`` pixels (Rerun's orbit camera)."""
    browser.page("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
    time.sleep(0.5)
    for _ in range(abs(int(zoom))):
        browser.page("Input.dispatchMouseEvent", type="mouseWheel", x=x, y=y, deltaX=0,
                     deltaY=20 if zoom > 0 else -20)  # fmt: skip
        time.sleep(0.2)
    if orbit != (0.0, 0.0):
        ev = {"button": "left", "clickCount": 1}
        browser.page("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
        browser.page("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, buttons=1, **ev)
        steps = 20
        for i in range(1, steps + 1):
            browser.page("Input.dispatchMouseEvent", type="mouseMoved", buttons=1,
                         x=x + orbit[0] * i / steps, y=y + orbit[1] * i / steps)  # fmt: skip
            time.sleep(0.05)
        browser.page("Input.dispatchMouseEvent", type="mouseReleased", x=x + orbit[0],
                     y=y + orbit[1], buttons=0, **ev)  # fmt: skip


def screenshot(
    rrd: Path,
    png: Path,
    exe: str,
    size: tuple[int, int],
    wait_s: float,
    renderer: str,
    zoom: float = 0.0,
    orbit: tuple[float, float] = (0.0, 0.0),
) -> None:
    """Serve ``rrd`` to Rerun's web viewer, load it in headless Chromium, move the 3D view's
    camera (``zoom``, ``orbit``) and capture the page once it has settled."""
    rerun = shutil.which("rerun", path=str(Path(sys.executable).parent)) or "rerun"
    http, ws, tcp = free_port(), free_port(), free_port()
    server = subprocess.Popen(
        [rerun, "--serve-web", "--bind", "127.0.0.1", "--port", str(tcp),
         "--web-viewer-port", str(http), "--ws-server-port", str(ws), str(rrd)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        time.sleep(3.0)
        with tempfile.TemporaryDirectory(prefix="chromium-") as profile:
            browser = Chromium(exe, size, Path(profile))
            try:
                browser.page("Page.enable")
                browser.page("Emulation.setDeviceMetricsOverride", width=size[0],
                             height=size[1], deviceScaleFactor=1, mobile=False)  # fmt: skip
                url = f"http://127.0.0.1:{http}/?url=ws://127.0.0.1:{ws}&renderer={renderer}"
                browser.page("Page.navigate", url=url)
                shot = settle(browser, wait_s, 4 * wait_s)
                if zoom or orbit != (0.0, 0.0):
                    mouse(browser, size[0] * 0.25, size[1] * 0.2, zoom, orbit)
                    shot = settle(browser, 8.0, 2 * wait_s)
                png.write_bytes(shot)
            finally:
                browser.close()
    finally:
        stop_group(server)


def shrink(png: Path, colours: int) -> None:
    from PIL import Image

    img = Image.open(png).convert("RGB")
    img.quantize(colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
        png, optimize=True
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--log", type=Path, help="a mock pick deploy log (default: run one)")
    p.add_argument("--frames", type=Path, help="the dataset the same deploy recorded")
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--watchdog-s", type=float, default=2.0)
    p.add_argument("--lift-m", type=float, default=0.04, help="cube lifted at least this")
    p.add_argument("--period", type=int, default=None, help="this period, not the chosen one")
    p.add_argument("--out", type=Path, default=REPO / "docs" / "img" / "view-mock-pick.png")
    p.add_argument("--rrd", type=Path, default=None, help="keep the cut recording here")
    p.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    p.add_argument("--size", default="1600x1000", help="the window, WxH")
    p.add_argument("--wait-s", type=float, default=20.0, help="wait at least this for the page")
    p.add_argument(
        "--renderer",
        default="webgpu",
        choices=("webgl", "webgpu"),
        help="the web viewer's (SwiftShader's WebGPU may refuse its buffers)",
    )
    p.add_argument("--zoom", type=float, default=4.0, help="3D view: wheel steps, + out")
    p.add_argument("--orbit-x", type=float, default=60.0, help="3D view: drag this many px")
    p.add_argument("--orbit-y", type=float, default=0.0)
    p.add_argument("--colours", type=int, default=256)
    args = p.parse_args()

    from sim2real.view.sources import LoadOptions, load_run

    with tempfile.TemporaryDirectory(prefix="view-shot-") as tmp:
        work = Path(tmp)
        if args.log is None:
            log, frames = deploy(work, args.episodes, args.seed, args.watchdog_s)
        else:
            log, frames = args.log, args.frames
        (run,) = load_run(log, LoadOptions(LABEL, frames))
        cols = {k: np.asarray(v) for k, v in run.columns.items()}
        k = pick_period(cols, args.lift_m) if args.period is None else args.period
        print(f"period {k}: episode {int(cols['episode'][k])} step {int(cols['step'][k])}, "
              f"grasped {int(cols['grasped'][k])}, cube blind {cols['cube_blind_s'][k]:.3f} s, "
              f"cube truth {np.round(cols['cube_true_m'][k], 3)} m, "
              f"estimate {np.round(cols['cube_est_m'][k], 3)} m, "
              f"tool {np.round(cols['true_tool_m'][k], 3)} m")  # fmt: skip
        rrd = args.rrd or work / "pick.rrd"
        write_rrd(cut(run, k), rrd)
        w, h = (int(v) for v in args.size.split("x"))
        screenshot(
            rrd,
            args.out,
            args.chromium,
            (w, h),
            args.wait_s,
            args.renderer,
            args.zoom,
            (args.orbit_x, args.orbit_y),
        )
        shrink(args.out, args.colours)
        print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
