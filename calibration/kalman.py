"""``KalmanTracker``: a 3-D position filter for triangulated markers, on filterpy.

- Constant-velocity (state p, v) or constant-acceleration (p, v, a) model; the time step comes
  from the measurement timestamps, so dropped or late frames are handled exactly.
- F, Q and H are built here by hand: filterpy 2.0.0's ``kinematic_kf(dim=3, order=1, dim_z=3)``
  builds an H that sums x+y+z in every row.
- Optionally two process-noise levels mixed by filterpy's ``IMMEstimator``: a *quiet* mode that
  smooths a still target hard and a *manoeuvre* mode that follows it when it moves. One noise
  level cannot do both (measured in ``bench/perception.py``: the level that follows a 0.3 Hz
  motion leaves a still target nearly as jittery as the raw measurements).
- Each measurement is gated by its Mahalanobis distance (χ², 3 dof) *before* the update, so an
  outlier never touches the state. After ``max_rejections`` rejections in a row the filter
  re-initialises from them (a too-confident filter would otherwise lock the gate shut), with a
  Theil–Sen line fit so that one outlier among them cannot place the new track.
- Missed detections only predict; a track that coasts longer than ``max_coast_s`` is dropped.
- :meth:`KalmanTracker.predict_at` extrapolates to any time without changing the state, for
  latency compensation.
- Orientation (a unit quaternion, w x y z) is smoothed by slerp with a time constant.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import IMMEstimator, KalmanFilter

from calibration.errors import ConfigError, UnknownNameError

# Model name → derivative order (1: velocity, 2: acceleration).
MOTION_MODELS: dict[str, int] = {"cv": 1, "ca": 2}

# χ² quantiles for 3 degrees of freedom.
CHI2_3DOF = {0.95: 7.81, 0.99: 11.34, 0.999: 16.27}


@dataclass(frozen=True)
class TrackerConfig:
    """Noise levels, gating and track management.

    ``process_std`` is the white-noise acceleration (cv, m/s²) or jerk (ca, m/s³), 1σ, of the
    quiet mode; ``manoeuvre_std`` the same for the manoeuvre mode (``None``: a single model).
    ``mode_switch_prob`` is the per-frame probability of switching between the two.
    The defaults were tuned with ``bench/perception.py``'s stereo error model at 20 Hz (marker
    noise 0.6–2 mm): a still target is smoothed ≥ 1.5×, 3 cm outliers are all rejected, and
    sinusoids up to 0.1 m at 1 Hz (4 m/s², 25 m/s³) are followed without a false rejection.
    Faster wobbles (e.g. 5 cm at 2 Hz, ~100 m/s³) exceed the manoeuvre mode: raise it, at the
    cost of letting larger outliers through.
    """

    model: str = "ca"
    measurement_std_m: float = 0.002
    process_std: float = 0.01
    manoeuvre_std: float | None = 20.0
    mode_switch_prob: float = 0.005
    gate_chi2: float = CHI2_3DOF[0.999]
    max_rejections: int = 5
    max_coast_s: float = 0.5
    init_velocity_std_mps: float = 0.5
    init_accel_std_mps2: float = 2.0
    orientation_time_constant_s: float = 0.1

    def __post_init__(self) -> None:
        if self.model not in MOTION_MODELS:
            raise UnknownNameError("motion model", self.model, MOTION_MODELS)
        positive = {
            "measurement_std_m": self.measurement_std_m,
            "process_std": self.process_std,
            "gate_chi2": self.gate_chi2,
            "max_coast_s": self.max_coast_s,
            "init_velocity_std_mps": self.init_velocity_std_mps,
            "init_accel_std_mps2": self.init_accel_std_mps2,
        }
        if self.manoeuvre_std is not None:
            positive["manoeuvre_std"] = self.manoeuvre_std
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a positive number, got {value!r}")
        if not 0.0 < self.mode_switch_prob < 0.5:
            raise ConfigError(f"mode_switch_prob must be in (0, 0.5), got {self.mode_switch_prob}")
        if self.max_rejections < 2:
            raise ConfigError(f"max_rejections must be ≥ 2, got {self.max_rejections}")
        if not (self.orientation_time_constant_s >= 0):
            raise ConfigError("orientation_time_constant_s must be ≥ 0")

    @property
    def order(self) -> int:
        return MOTION_MODELS[self.model]

    @property
    def dim_x(self) -> int:
        return 3 * (self.order + 1)

    @property
    def mode_stds(self) -> tuple[float, ...]:
        if self.manoeuvre_std is None:
            return (self.process_std,)
        return (self.process_std, self.manoeuvre_std)


def transition_matrix(dt_s: float, order: int) -> np.ndarray:
    """F for the state [p(3), v(3)] (order 1) or [p, v, a] (order 2), in blocks of I₃."""
    n = order + 1
    block = np.eye(n)
    for k in range(1, n):
        block += np.diag(np.full(n - k, dt_s**k / math.factorial(k)), k)
    return np.kron(block, np.eye(3))


def process_noise(dt_s: float, order: int, std: float) -> np.ndarray:
    """Q for a piecewise-constant white acceleration (order 1) or jerk (order 2), per axis."""
    gains = np.array(
        [dt_s ** (order + 1 - k) / math.factorial(order + 1 - k) for k in range(order + 1)]
    )
    return np.kron(np.outer(gains, gains) * std**2, np.eye(3))


def measurement_matrix(order: int) -> np.ndarray:
    """H = [I₃ 0 …]: the filter observes position only."""
    H = np.zeros((3, 3 * (order + 1)))
    H[:, :3] = np.eye(3)
    return H


STATUSES = (
    "uninitialised", "initialised", "updated", "rejected", "reinitialised", "predicted", "lost",
)  # fmt: skip


@dataclass(frozen=True, eq=False)
class Estimate:
    """The tracker's belief at ``timestamp_s``.

    ``status`` says what the last call did: ``updated`` (measurement accepted), ``rejected``
    (gated out; the prediction is returned), ``predicted`` (no measurement), ``initialised`` /
    ``reinitialised`` (state set from measurements), ``lost`` / ``uninitialised`` (no track).
    ``nis`` is the measurement's Mahalanobis² distance (normalised innovation squared).
    """

    timestamp_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    covariance_m2: np.ndarray
    status: str
    nis: float | None = None
    orientation_wxyz: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return self.status not in ("uninitialised", "lost")

    @property
    def position_std_m(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance_m2))


@dataclass
class TrackerStats:
    """How often each outcome happened since construction."""

    updated: int = 0
    rejected: int = 0
    reinitialised: int = 0
    predicted: int = 0
    lost: int = 0


def slerp(q0: np.ndarray, q1: np.ndarray, alpha: float) -> np.ndarray:
    """Spherical interpolation between unit quaternions, the short way round."""
    dot = float(np.dot(q0, q1))
    if dot < 0.0:  # q and −q are the same rotation
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + alpha * (q1 - q0)
    else:
        theta = math.acos(min(dot, 1.0))
        q = (math.sin((1 - alpha) * theta) * q0 + math.sin(alpha * theta) * q1) / math.sin(theta)
    return np.asarray(q / np.linalg.norm(q))


def theil_sen(t_s: np.ndarray, z: np.ndarray, t_eval_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Robust line fit per axis: position at ``t_eval_s`` and velocity (median pairwise slope)."""
    i, j = np.triu_indices(len(t_s), k=1)
    dt = t_s[j] - t_s[i]
    ok = dt > 1e-9
    if not np.any(ok):
        return np.median(z, axis=0), np.zeros(z.shape[1])
    slopes = (z[j[ok]] - z[i[ok]]) / dt[ok, None]
    velocity = np.median(slopes, axis=0)
    position = np.median(z + (t_eval_s - t_s)[:, None] * velocity, axis=0)
    return position, velocity


class KalmanTracker:
    """Filters 3-D positions (and smooths orientations) of one target. See the module doc."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        c = self.config
        self._H = measurement_matrix(c.order)
        self._R = np.eye(3) * c.measurement_std_m**2
        self._filters = []
        for _ in c.mode_stds:
            kf = KalmanFilter(dim_x=c.dim_x, dim_z=3)
            kf.H = self._H.copy()
            kf.R = self._R.copy()
            self._filters.append(kf)
        n = len(self._filters)
        self._M = np.full((n, n), c.mode_switch_prob / max(n - 1, 1))
        np.fill_diagonal(self._M, 1.0 - c.mode_switch_prob if n > 1 else 1.0)
        self._imm: IMMEstimator | None = None
        self.stats = TrackerStats()
        self._t: float | None = None
        self._t_accepted = 0.0
        self._rejected: deque[tuple[float, np.ndarray]] = deque(maxlen=c.max_rejections)
        self._q: np.ndarray | None = None
        self._initialised = False

    # ------------------------------------------------------------------ state
    @property
    def initialised(self) -> bool:
        return self._initialised

    @property
    def consecutive_rejections(self) -> int:
        return len(self._rejected)

    @property
    def mode_probabilities(self) -> np.ndarray:
        """Probability of (quiet, manoeuvre); ``[1.0]`` for a single model."""
        return np.ones(1) if self._imm is None else np.asarray(self._imm.mu, np.float64).copy()

    @property
    def _x(self) -> np.ndarray:
        return np.asarray(self._imm.x if self._imm is not None else self._filters[0].x).ravel()

    @property
    def _P(self) -> np.ndarray:
        return np.asarray(self._imm.P if self._imm is not None else self._filters[0].P)

    def reset(self) -> None:
        """Forget the track; the next measurement initialises a new one."""
        self._initialised = False
        self._t = None
        self._q = None
        self._rejected.clear()

    def _init_state(self, z: np.ndarray, v: np.ndarray, t: float, pos_var: float) -> None:
        c = self.config
        x = np.zeros(c.dim_x)
        x[:3], x[3:6] = z, v
        variances = [pos_var, c.init_velocity_std_mps**2, c.init_accel_std_mps2**2]
        P = np.kron(np.diag(variances[: c.order + 1]), np.eye(3))
        for kf in self._filters:
            kf.x = x.copy()
            kf.P = P.copy()
        if len(self._filters) > 1:
            mu = np.full(len(self._filters), 1.0 / len(self._filters))
            self._imm = IMMEstimator(self._filters, mu, self._M)
        self._t = t
        self._t_accepted = t
        self._rejected.clear()
        self._initialised = True

    def _estimate(
        self, t: float, x: np.ndarray, P: np.ndarray, status: str, nis: float | None
    ) -> Estimate:
        return Estimate(
            timestamp_s=t,
            position_m=x[:3].copy(),
            velocity_mps=x[3:6].copy(),
            covariance_m2=P[:3, :3].copy(),
            status=status,
            nis=nis,
            orientation_wxyz=None if self._q is None else self._q.copy(),
        )

    def _dt(self, timestamp_s: float) -> float:
        assert self._t is not None
        dt = timestamp_s - self._t
        if not math.isfinite(timestamp_s) or dt < -1e-9:
            raise ConfigError(
                f"timestamp {timestamp_s!r} s is before the previous one ({self._t} s); "
                "timestamps must not go backwards"
            )
        return max(dt, 0.0)

    def _advance(self, timestamp_s: float) -> None:
        dt = self._dt(timestamp_s)
        if dt > 0:
            F = transition_matrix(dt, self.config.order)
            for kf, std in zip(self._filters, self.config.mode_stds, strict=True):
                kf.F = F
                kf.Q = process_noise(dt, self.config.order, std)
            if self._imm is not None:
                self._imm.predict()
            else:
                self._filters[0].predict()
        self._t = timestamp_s

    def _coast_modes(self) -> None:
        """After a predict with no update, carry the mode probabilities through the Markov chain
        (mu ← mu·M) and recompute the mixing weights, as the update step would have done."""
        if self._imm is None:
            return
        imm = self._imm
        imm.mu = np.asarray(imm.mu, np.float64) @ self._M
        imm.cbar = imm.mu @ self._M
        imm.omega = (self._M * imm.mu[:, None]) / imm.cbar[None, :]

    def _smooth_orientation(self, q_wxyz: np.ndarray | None, dt: float) -> None:
        if q_wxyz is None:
            return
        q = np.asarray(q_wxyz, np.float64).reshape(4)
        q = q / np.linalg.norm(q)
        tau = self.config.orientation_time_constant_s
        if self._q is None or tau == 0:
            self._q = q if self._q is None or np.dot(self._q, q) >= 0 else -q
            return
        alpha = 1.0 - math.exp(-dt / tau) if dt > 0 else 0.0
        self._q = slerp(self._q, q, alpha)

    # ------------------------------------------------------------------ public API
    def update(
        self,
        position_m: np.ndarray,
        timestamp_s: float,
        orientation_wxyz: np.ndarray | None = None,
    ) -> Estimate:
        """Predict to ``timestamp_s``, gate the measurement, and update if it passes."""
        z = np.asarray(position_m, np.float64).reshape(3)
        if not np.all(np.isfinite(z)):
            return self.predict(timestamp_s)
        if not self._initialised:
            self._init_state(z, np.zeros(3), timestamp_s, self.config.measurement_std_m**2)
            self._smooth_orientation(orientation_wxyz, 0.0)
            return self._estimate(timestamp_s, self._x, self._P, "initialised", None)
        t_prev = self._t_accepted
        self._advance(timestamp_s)
        x, P = self._x, self._P
        nis = self._gate_distance(z)
        if nis > self.config.gate_chi2:
            return self._reject(z, timestamp_s, x, P, nis, orientation_wxyz)
        if self._imm is not None:
            self._imm.update(z)
        else:
            self._filters[0].update(z)
        self._rejected.clear()
        self._t_accepted = timestamp_s
        self.stats.updated += 1
        self._smooth_orientation(orientation_wxyz, timestamp_s - t_prev)
        return self._estimate(timestamp_s, self._x, self._P, "updated", nis)

    def _gate_distance(self, z: np.ndarray) -> float:
        """Mahalanobis² of ``z`` from the prediction, the smallest over the motion modes.

        Gating each mode separately matters when a still target starts to move: the combined
        prior is still mostly the quiet mode's, and would reject the very measurements that let
        the IMM switch to the manoeuvre mode.
        """
        best = math.inf
        for kf in self._filters:
            x = np.ravel(kf.x)
            innovation = z - x[:3]
            S = np.asarray(kf.P)[:3, :3] + self._R
            best = min(best, float(innovation @ np.linalg.solve(S, innovation)))
        return best

    def _reject(
        self,
        z: np.ndarray,
        t: float,
        x: np.ndarray,
        P: np.ndarray,
        nis: float,
        orientation_wxyz: np.ndarray | None,
    ) -> Estimate:
        self._rejected.append((t, z))
        self.stats.rejected += 1
        self._coast_modes()
        if len(self._rejected) >= self.config.max_rejections:
            times = np.array([r[0] for r in self._rejected])
            points = np.array([r[1] for r in self._rejected])
            position, velocity = theil_sen(times, points, t)
            self.stats.reinitialised += 1
            self._q = None
            self._init_state(position, velocity, t, 4.0 * self.config.measurement_std_m**2)
            self._smooth_orientation(orientation_wxyz, 0.0)
            return self._estimate(t, self._x, self._P, "reinitialised", nis)
        if t - self._t_accepted > self.config.max_coast_s:
            return self._lose(t)
        return self._estimate(t, x, P, "rejected", nis)

    def predict(self, timestamp_s: float) -> Estimate:
        """No measurement this frame: advance the state to ``timestamp_s`` and return it."""
        if not self._initialised:
            return self._empty(timestamp_s, "uninitialised")
        self._advance(timestamp_s)
        self._coast_modes()
        self.stats.predicted += 1
        if timestamp_s - self._t_accepted > self.config.max_coast_s:
            return self._lose(timestamp_s)
        return self._estimate(timestamp_s, self._x, self._P, "predicted", None)

    def predict_at(self, timestamp_s: float) -> Estimate:
        """Where the target will be at ``timestamp_s`` (e.g. now + latency); state unchanged."""
        if not self._initialised:
            return self._empty(timestamp_s, "uninitialised")
        dt = self._dt(timestamp_s)
        if dt == 0.0:
            return self._estimate(timestamp_s, self._x, self._P, "predicted", None)
        F = transition_matrix(dt, self.config.order)
        mu = self.mode_probabilities
        priors = [(np.ravel(kf.x), np.asarray(kf.P)) for kf in self._filters]
        if self._imm is not None:  # the IMM's own mixing step, as IMMEstimator.predict does it
            omega = np.asarray(self._imm.omega)
            mixed = []
            for i in range(len(priors)):
                x_i = sum(
                    (omega[j, i] * xj for j, (xj, _) in enumerate(priors)),
                    np.zeros(len(priors[0][0])),
                )
                P_i = sum(
                    (
                        omega[j, i] * (Pj + np.outer(xj - x_i, xj - x_i))
                        for j, (xj, Pj) in enumerate(priors)
                    ),
                    np.zeros_like(priors[0][1]),
                )
                mixed.append((x_i, P_i))
            priors = mixed
        xs = [F @ x for x, _ in priors]
        Ps = [
            F @ P @ F.T + process_noise(dt, self.config.order, std)
            for (_, P), std in zip(priors, self.config.mode_stds, strict=True)
        ]
        x = sum((m * xi for m, xi in zip(mu, xs, strict=True)), np.zeros(self.config.dim_x))
        P = sum(
            (m * (Pi + np.outer(xi - x, xi - x)) for m, xi, Pi in zip(mu, xs, Ps, strict=True)),
            np.zeros((self.config.dim_x, self.config.dim_x)),
        )
        return self._estimate(timestamp_s, x, P, "predicted", None)

    def _lose(self, timestamp_s: float) -> Estimate:
        est = self._estimate(timestamp_s, self._x, self._P, "lost", None)
        self.stats.lost += 1
        self.reset()
        return est

    def _empty(self, timestamp_s: float, status: str) -> Estimate:
        nan3 = np.full(3, np.nan)
        return Estimate(timestamp_s, nan3, nan3.copy(), np.full((3, 3), np.nan), status)
