"""The navigation filter of :mod:`cwh_envs.navigation`, compiled (numba) for one chaser.

The numpy filter steps a batch; on one chaser its time is array-call overhead (about 100-140 µs a step
with its sigma and thrust command, measured alone: benchmarks/bench_flight_path.py). :class:`CompiledNavigationFilter` is the same Kalman filter (the same model, prior,
process floor, innovation monitor and ``sigma``), one episode at a time, compiled once and cached
on disk:

    from cwh_envs.compiled_navigation import CompiledNavigationFilter

    navigator = CompiledNavigationFilter(problem, bounds)
    navigator.start(measurement)                   # (6,), the episode's first
    estimate = navigator.step(thrust, measurement)  # the thrust (3,) N commanded since the last one
    sigma, gain = navigator.sigma(), navigator.thrust_gain()

tests/test_compiled_filter.py steps both filters on the same dispersed measurements and compares.
numba is an optional dependency (``pip install 'cwh-autoresearch[fast]'``).
"""

from __future__ import annotations

import math

import numpy as np

try:
    from numba import njit
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        "cwh_envs.compiled_navigation needs numba, which is not installed: pip install 'cwh-autoresearch[fast]'",
        name=err.name,
    ) from err

from cwh_envs.compiled_filter import _finite
from cwh_envs.navigation import _N, NOISE_PRIOR_STEPS, PROCESS_FLOOR, NavigationFilter
from cwh_envs.problems import DockingProblem
from cwh_envs.robust_cbf import ErrorBounds


class CompiledNavigationFilter:
    """:class:`cwh_envs.navigation.NavigationFilter` for one episode at a time (module docstring)."""

    def __init__(self, problem: DockingProblem, bounds: ErrorBounds) -> None:
        reference = NavigationFilter(problem, bounds)  # its checks of the bounds, and its constants
        self.a, self.b = np.ascontiguousarray(reference.a), np.ascontiguousarray(reference.b)
        self.noise = np.ascontiguousarray(np.diag(reference.noise))  # (6,): R's diagonal
        self.prior = np.ascontiguousarray(reference.prior)
        self.mean = np.zeros(_N)
        self.covariance = np.zeros((_N, _N))
        self.innovation = np.zeros(2)  # normalised innovation squared, summed; and the count
        self.started = False

    def start(self, measurement) -> None:
        """Begin an episode at its first measurement (6,)."""
        y = self._vector(measurement, 6, "measurement")
        self.mean[:] = 0.0
        self.mean[:6] = y
        self.covariance[:] = 0.0
        for i in range(6):
            self.covariance[i, i] = self.noise[i]
        for i in range(9):
            self.covariance[6 + i, 6 + i] = self.prior[i]
        self.innovation[:] = NOISE_PRIOR_STEPS * 6.0, NOISE_PRIOR_STEPS
        self.started = True

    def step(self, thrust, measurement) -> np.ndarray:
        """The estimate of ``[r, v]`` (6,) after the thrust (3,) N commanded and the new measurement (6,)."""
        if not self.started:
            raise RuntimeError("step() before start(): the filter begins at an episode's first measurement")
        u = self._vector(thrust, 3, "thrust")
        y = self._vector(measurement, 6, "measurement")
        _step(self.mean, self.covariance, self.innovation, self.a, self.b, self.noise, u, y)
        return self.mean[:6].copy()

    def sigma(self) -> np.ndarray:
        """The one-sigma estimate error (2,): position m and velocity m/s, as NavigationFilter.sigma."""
        return _sigma(self.covariance, self.innovation)

    def thrust_gain(self) -> np.ndarray:
        """The estimated ``G`` (3, 3): the thrust delivered per thrust commanded."""
        return np.eye(3) + self.mean[6:].reshape(3, 3)

    def command(self, action) -> np.ndarray:
        """The action (3,) to command so that the estimated ``G`` delivers ``action``: ``G_hat^-1 action``
        clipped to the box [-1, 1], as :func:`cwh_envs.rollout.fly` commands through the filter."""
        return _command(self.mean, self._vector(action, 3, "action"))

    @staticmethod
    def _vector(values, n: int, name: str) -> np.ndarray:
        # the finiteness check compiled: numpy's costs as much as the filter's step on one chaser
        out = np.asarray(values, dtype=np.float64)
        if out.shape != (n,) or not _finite(out):
            raise ValueError(f"{name} must be {n} finite numbers, got {values!r}")
        return out


@njit(cache=True)
def _step(mean, covariance, innovation, a, b, noise, u, y):
    """NavigationFilter.step for one row, in place: the prediction through ``F = [[A, B U(u)], [0, I]]``
    and the update on ``y = [r, v] + n``. ``F``'s blocks are used as they are (``U(u) theta = (G - I) u``:
    ``(B U)[r, 3 j + k] = B[r, j] u[k]``), so that the product costs a third of a dense one."""
    bu = np.empty((6, 9))
    for r in range(6):
        for j in range(3):
            for k in range(3):
                bu[r, 3 * j + k] = b[r, j] * u[k]
    predicted = mean.copy()
    for r in range(6):
        total = 0.0
        for c in range(6):
            total += a[r, c] * mean[c]
        for c in range(9):
            total += bu[r, c] * mean[6 + c]
        for j in range(3):
            total += b[r, j] * u[j]
        predicted[r] = total
    fp = covariance.copy()  # F P: rows 6.. are P's
    for r in range(6):
        for c in range(_N):
            total = 0.0
            for m in range(6):
                total += a[r, m] * covariance[m, c]
            for m in range(9):
                total += bu[r, m] * covariance[6 + m, c]
            fp[r, c] = total
    p = fp.copy()  # (F P) F^T: columns 6.. are F P's
    for r in range(_N):
        for c in range(6):
            total = 0.0
            for m in range(6):
                total += fp[r, m] * a[c, m]
            for m in range(9):
                total += fp[r, 6 + m] * bu[c, m]
            p[r, c] = total
    for i in range(6):
        p[i, i] += PROCESS_FLOOR * noise[i]
    # S = P_xx + R, by Cholesky: S = L L^T
    chol = np.zeros((6, 6))
    for i in range(6):
        for j in range(i + 1):
            total = p[i, j] + (noise[i] if i == j else 0.0)
            for m in range(j):
                total -= chol[i, m] * chol[j, m]
            chol[i, j] = math.sqrt(total) if i == j else total / chol[j, j]
    # K^T = S^-1 P[:6, :] (P is symmetric): two triangular solves per column
    gain_t = np.empty((6, _N))
    for c in range(_N):
        for i in range(6):
            total = p[i, c]
            for m in range(i):
                total -= chol[i, m] * gain_t[m, c]
            gain_t[i, c] = total / chol[i, i]
        for i in range(5, -1, -1):
            total = gain_t[i, c]
            for m in range(i + 1, 6):
                total -= chol[m, i] * gain_t[m, c]
            gain_t[i, c] = total / chol[i, i]
    residual = y - predicted[:6]
    solved = np.empty(6)  # L^-1 residual: its squared norm is residual^T S^-1 residual
    nis = 0.0
    for i in range(6):
        total = residual[i]
        for m in range(i):
            total -= chol[i, m] * solved[m]
        solved[i] = total / chol[i, i]
        nis += solved[i] * solved[i]
    innovation[0] += nis
    innovation[1] += 1.0
    for r in range(_N):
        total = predicted[r]
        for m in range(6):
            total += gain_t[m, r] * residual[m]
        mean[r] = total
    for r in range(_N):
        for c in range(_N):
            total = p[r, c]
            for m in range(6):
                total -= gain_t[m, r] * p[m, c]
            covariance[r, c] = total


@njit(cache=True)
def _largest_eigenvalue(m, start):
    """The largest eigenvalue of the symmetric 3x3 block of ``m`` at ``start``, in closed form
    (Smith 1961: the trigonometric solution of the characteristic cubic)."""
    a00, a11, a22 = m[start, start], m[start + 1, start + 1], m[start + 2, start + 2]
    a01, a02, a12 = m[start, start + 1], m[start, start + 2], m[start + 1, start + 2]
    off = a01 * a01 + a02 * a02 + a12 * a12
    if off == 0.0:
        return max(a00, a11, a22)
    q = (a00 + a11 + a22) / 3.0
    spread = math.sqrt(((a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * off) / 6.0)
    b00, b11, b22 = (a00 - q) / spread, (a11 - q) / spread, (a22 - q) / spread
    b01, b02, b12 = a01 / spread, a02 / spread, a12 / spread
    half_det = (
        b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    ) / 2.0
    phi = math.acos(min(max(half_det, -1.0), 1.0)) / 3.0
    return q + 2.0 * spread * math.cos(phi)


@njit(cache=True)
def _sigma(covariance, innovation):
    scale = math.sqrt(max(innovation[0] / (6.0 * innovation[1]), 1.0))
    out = np.empty(2)
    out[0] = math.sqrt(_largest_eigenvalue(covariance, 0)) * scale
    out[1] = math.sqrt(_largest_eigenvalue(covariance, 3)) * scale
    return out


@njit(cache=True)
def _command(mean, action):
    """``clip(G_hat^-1 action, -1, 1)`` by Cramer's rule, ``G_hat = I + vec^-1(theta)``."""
    g = np.eye(3)
    for i in range(3):
        for j in range(3):
            g[i, j] += mean[6 + 3 * i + j]
    det = (
        g[0, 0] * (g[1, 1] * g[2, 2] - g[1, 2] * g[2, 1])
        - g[0, 1] * (g[1, 0] * g[2, 2] - g[1, 2] * g[2, 0])
        + g[0, 2] * (g[1, 0] * g[2, 1] - g[1, 1] * g[2, 0])
    )
    out = np.empty(3)
    for column in range(3):
        m = g.copy()
        for i in range(3):
            m[i, column] = action[i]
        minor = (
            m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
            - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
            + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
        )
        out[column] = min(max(minor / det, -1.0), 1.0)
    return out
