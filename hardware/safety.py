"""Safety that is always on, in front of every Arm backend.

Order of the filter: NaN/inf rejection -> joint limits -> per-step clamp (on by default) ->
workspace guard (the spec's FK: tool and elbow above the table plus a margin, inside a box).

Non-finite policy (decided here, documented in docs/hardware.md): a NaN or ±inf entry is *held*:
that actuator keeps its previously sent target, the others still move, and the event is counted
in ``SafetyFilter.stats`` (and logged once). Raising instead would hand a policy bug to the
caller's error handling mid-motion, and an unhandled exception ends in torque-off: the arm drops.
Holding is the state the firmware's own watchdog falls back to as well. ``on_nonfinite="raise"``
exists for tests and offline checks. A command of the wrong shape is a programming error and always
raises SafetyError.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from itertools import combinations
from types import FrameType
from typing import Any, Protocol

import numpy as np

from hardware.errors import SafetyError
from hardware.spec import ArmSpec

log = logging.getLogger(__name__)

NONFINITE_POLICIES = ("hold", "raise")


@dataclass
class SafetyStats:
    commands: int = 0
    nonfinite: int = 0  # commands with at least one NaN/inf entry
    limit_clamped: int = 0  # commands with at least one entry outside the joint limits
    step_clamped: int = 0  # commands with at least one entry over the per-step clamp
    workspace_clamped: int = 0  # commands the workspace guard held or shortened


_BISECT_STEPS = 12  # resolution of the projection back along a step: 1/4096 of it
# A previous target outside the workspace by less than this is a boundary command rounded to servo
# units (under 0.5 mm for the shipped spec), not an arm left outside: it earns no allowance, so
# rounding cannot ratchet the arm outwards one step at a time.
_ROUNDING_TOLERANCE_M = 1e-3


class WorkspaceGuard:
    """The spec's analytic FK for the tool point and the elbow against the table plane (plus a
    margin) and the workspace box.

    The filter runs every control period, so the FK here is scalar ``math`` on constants read once
    (about 1 µs); ``ArmSpec.forward_kinematics``/``elbow_position`` are the reference it is tested
    against."""

    def __init__(self, spec: ArmSpec) -> None:
        j0, j1, j2 = spec.joints
        L = spec.links
        self._signs = (j0.sign, j1.sign, j2.sign)
        self._l1, self._l2 = L.upper_arm_m, L.forearm_m
        self._h, self._tf, self._td = L.base_height_m, L.tool_forward_m, L.tool_down_m
        self.floor_z_m = spec.workspace.table_z_m + spec.workspace.margin_m
        box_min, box_max = spec.workspace_box_m()
        self.box_min_m: tuple[float, ...] = tuple(float(v) for v in box_min)
        self.box_max_m: tuple[float, ...] = tuple(float(v) for v in box_max)

    def excess_m(self, q_rad: Any) -> float:
        """How far (m) the worse of tool and elbow lies outside the workspace; <= 0 inside.
        Takes joint angles, or the actuator vector (the gripper entry is ignored)."""
        s0, s1, s2 = self._signs
        q0, q1, q2 = (q_rad.tolist() if isinstance(q_rad, np.ndarray) else q_rad)[:3]
        yaw = s0 * q0
        a1 = s1 * q1
        a12 = a1 + s2 * q2
        cy, sy = math.cos(yaw), math.sin(yaw)
        r_elbow = self._l1 * math.sin(a1)
        z_elbow = self._h + self._l1 * math.cos(a1)
        r_tool = r_elbow + self._l2 * math.cos(a12) + self._tf
        z_tool = z_elbow - self._l2 * math.sin(a12) - self._td
        lo, hi = self.box_min_m, self.box_max_m
        worst = -math.inf
        for r, z in ((r_tool, z_tool), (r_elbow, z_elbow)):
            x, y = r * cy, r * sy
            worst = max(
                worst,
                self.floor_z_m - z,
                lo[0] - x,
                x - hi[0],
                lo[1] - y,
                y - hi[1],
                lo[2] - z,
                z - hi[2],
            )
        return worst

    def inside(self, q_rad: Any) -> bool:
        return self.excess_m(q_rad) <= 0.0


class SafetyFilter:
    """Makes any policy output safe to send: finite, inside the limits, at most one step away,
    with the tool and the elbow inside the workspace."""

    def __init__(
        self,
        spec: ArmSpec,
        max_step_rad: float | None = None,
        on_nonfinite: str = "hold",
    ) -> None:
        if on_nonfinite not in NONFINITE_POLICIES:
            raise SafetyError(
                f"on_nonfinite {on_nonfinite!r} is not one of {', '.join(NONFINITE_POLICIES)}"
            )
        step = spec.safety.max_step_rad if max_step_rad is None else float(max_step_rad)
        if not np.isfinite(step) or step <= 0:
            raise SafetyError(
                f"max_step_rad must be a finite number > 0 (the clamp cannot be switched off), "
                f"got {max_step_rad!r}"
            )
        self.spec = spec
        self.n = spec.n_actuators
        self.lower_rad = spec.actuator_lower_rad.astype(float)
        self.upper_rad = spec.actuator_upper_rad.astype(float)
        self.max_step_rad = step
        self.on_nonfinite = on_nonfinite
        self.guard = WorkspaceGuard(spec)
        n_joints = spec.n_joints
        # joint subsets to try when a whole step leaves the workspace, largest first: moving only
        # some joints lets the tool slide along the table instead of stopping dead on it
        self._subsets = [
            np.isin(np.arange(self.n), subset)
            for k in range(n_joints - 1, 0, -1)
            for subset in combinations(range(n_joints), k)
        ]
        self._joint_mask = np.arange(self.n) < n_joints
        self.stats = SafetyStats()
        self._warned = False
        self._warned_workspace = False

    def clip_to_limits(self, q_rad: np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(q_rad, dtype=float), self.lower_rad, self.upper_rad)

    def check_shape(self, targets_rad: Any) -> np.ndarray:
        try:
            q = np.asarray(targets_rad, dtype=float)
        except (TypeError, ValueError):
            raise SafetyError(
                f"targets must be {self.n} numbers ({', '.join(self.spec.actuator_names)}), "
                f"got {targets_rad!r}"
            ) from None
        if q.shape != (self.n,):
            raise SafetyError(
                f"targets must have shape ({self.n},) for actuators "
                f"{', '.join(self.spec.actuator_names)}, got shape {q.shape}"
            )
        return q

    def filter(self, targets_rad: Any, previous_sent_rad: np.ndarray) -> np.ndarray:
        """Safe targets (n_actuators,) given the last targets that actually went out."""
        q = self.check_shape(targets_rad)
        prev = np.asarray(previous_sent_rad, dtype=float)
        if prev.shape != (self.n,) or not np.all(np.isfinite(prev)):
            raise SafetyError(f"previous targets must be {self.n} finite numbers, got {prev!r}")
        prev = self.clip_to_limits(prev)
        self.stats.commands += 1
        bad = ~np.isfinite(q)
        if bad.any():
            self.stats.nonfinite += 1
            names = [n for n, b in zip(self.spec.actuator_names, bad, strict=True) if b]
            if self.on_nonfinite == "raise":
                raise SafetyError(f"non-finite target(s) for {', '.join(names)}: {q.tolist()}")
            if not self._warned:
                log.warning("non-finite target(s) for %s: holding them", ", ".join(names))
                self._warned = True
            q = np.where(bad, prev, q)
        limited = np.clip(q, self.lower_rad, self.upper_rad)
        if np.any(limited != q):
            self.stats.limit_clamped += 1
        stepped = np.clip(limited, prev - self.max_step_rad, prev + self.max_step_rad)
        if np.any(stepped != limited):
            self.stats.step_clamped += 1
        # prev is inside the limits, so a step towards a target inside the limits stays inside;
        # the final clip only guards against float rounding at the boundary.
        out = np.clip(stepped, self.lower_rad, self.upper_rad)
        return self._guard_workspace(out, prev)

    def _guard_workspace(self, q: np.ndarray, prev: np.ndarray) -> np.ndarray:
        """``q`` if the workspace allows it, else the safe point nearest to it among: the step
        with only some joints moved, the step shortened towards ``prev``, and ``prev`` itself.

        From a safe ``prev`` every result is inside. From an unsafe ``prev`` (an arm switched on
        where it was left) a command may not go further out, so the arm can still be driven back
        in. Every candidate mixes ``prev`` and ``q`` per joint, so limits and the clamp hold.
        Backends round the result to servo units, so what a device receives at the boundary can
        sit outside by that rounding (under 0.5 mm for the shipped spec)."""
        guard = self.guard
        excess_m = guard.excess_m(q)
        if excess_m <= 0.0:  # the hot path: one FK of a command that is inside
            return q
        prev_excess_m = guard.excess_m(prev)
        allowed_m = prev_excess_m if prev_excess_m > _ROUNDING_TOLERANCE_M else 0.0
        if excess_m <= allowed_m:
            return q
        self.stats.workspace_clamped += 1
        if not self._warned_workspace:
            log.warning(
                "workspace guard: targets %s would put the tool or elbow below the table or "
                "outside the box: holding/shortening the step",
                np.round(q, 3).tolist(),
            )
            self._warned_workspace = True
        hold = np.where(self._joint_mask, prev, q)  # hold the joints, the gripper still moves
        best, best_d = hold, float(np.sum((hold - q) ** 2))
        for mask in self._subsets:
            cand = np.where(mask, q, hold)
            d = float(np.sum((cand - q) ** 2))
            if d < best_d and guard.excess_m(cand) <= allowed_m:
                best, best_d = cand, d
        lo_t, hi_t = 0.0, 1.0  # back along the step: lo_t is allowed (or 0), hi_t is not
        for _ in range(_BISECT_STEPS):
            mid = 0.5 * (lo_t + hi_t)
            if guard.excess_m(prev + mid * (q - prev)) <= allowed_m:
                lo_t = mid
            else:
                hi_t = mid
        cand = np.where(self._joint_mask, prev + lo_t * (q - prev), q)
        if lo_t > 0.0 and float(np.sum((cand - q) ** 2)) < best_d:
            best = cand
        return best


class Watchdog:
    """Calls ``on_expire`` once when ``kick()`` has not been called for ``timeout_s``.

    The host-side twin of the firmware watchdog: it catches a control loop that stalls (a hung
    policy, a debugger breakpoint) on backends whose device has no watchdog of its own."""

    def __init__(
        self, timeout_s: float, on_expire: Callable[[], None], name: str = "watchdog"
    ) -> None:
        if not np.isfinite(timeout_s) or timeout_s <= 0:
            raise SafetyError(f"watchdog timeout must be > 0 s, got {timeout_s!r}")
        self.timeout_s = float(timeout_s)
        self._on_expire = on_expire
        self._name = name
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._deadline: float | None = None
        self._stop = False
        self._thread: threading.Thread | None = None
        self.fired = 0

    def arm(self) -> None:
        """Start (or restart) counting from now."""
        with self._lock:
            self._deadline = time.monotonic() + self.timeout_s
            if self._thread is None or not self._thread.is_alive():
                self._stop = False
                self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
                self._thread.start()
        self._wake.set()

    def kick(self) -> None:
        with self._lock:
            if self._deadline is not None:
                self._deadline = time.monotonic() + self.timeout_s

    def disarm(self) -> None:
        with self._lock:
            self._deadline = None
        self._wake.set()

    def stop(self) -> None:
        with self._lock:
            self._deadline = None
            self._stop = True
        self._wake.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)
        self._thread = None

    @property
    def armed(self) -> bool:
        return self._deadline is not None

    def _run(self) -> None:
        while True:
            with self._lock:
                if self._stop:
                    return
                deadline = self._deadline
            if deadline is None:
                self._wake.wait(1.0)
                self._wake.clear()
                continue
            remaining = deadline - time.monotonic()
            if remaining > 0:
                self._wake.wait(remaining)
                self._wake.clear()
                continue
            with self._lock:
                if self._deadline is None or self._deadline > time.monotonic():
                    continue
                self._deadline = None
            self.fired += 1
            try:
                self._on_expire()
            except Exception:  # the watchdog must survive a failing e-stop to report it
                log.exception("%s: e-stop handler failed", self._name)


class EStoppable(Protocol):
    def estop(self, reason: str) -> None: ...


@contextmanager
def estop_on_signals(
    arm: EStoppable, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
) -> Iterator[None]:
    """On SIGINT/SIGTERM inside the block: e-stop the arm (hold, then torque off), then leave as
    the signal would have (KeyboardInterrupt, or SystemExit(128 + signum)). Main thread only.

    The handler itself only raises: the e-stop runs as that exception leaves the block, after any
    serial transaction the signal interrupted has unwound (doing I/O inside the handler could
    re-enter a transaction that holds the port's lock and deadlock)."""
    previous: dict[int, Any] = {}
    fired: list[int] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        fired.append(signum)
        for sig, prev in previous.items():
            signal.signal(sig, prev)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)

    for sig in signals:
        previous[sig] = signal.signal(sig, handler)
    try:
        yield
    except BaseException:
        if fired:
            try:
                arm.estop(f"signal {signal.Signals(fired[0]).name}")
            except Exception:  # still leave with the signal's exception
                log.exception("e-stop after signal %s failed", fired[0])
        raise
    finally:
        for sig, prev in previous.items():
            if signal.getsignal(sig) is handler:
                signal.signal(sig, prev)
