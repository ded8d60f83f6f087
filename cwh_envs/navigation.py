"""A navigation filter for the dispersed flight (issue 58): a Kalman filter of the CWH relative state
that also estimates the episode's thrust error, from the navigation estimate and the thrust commanded.

Under :mod:`cwh_envs.dispersions` the navigation estimate is the true state plus white noise, fresh
each step: a raw sensor, not a navigation solution. Flight software runs a filter between the two;
a controller that feeds the raw estimate into a feedback gain injects the noise into the thrust.
The thrust error of an episode is one constant matrix, ``u_true = G u`` (scale, mass, misalignment),
so the filter carries ``theta = vec(G - I)`` (row-major, 9 numbers) as constant states beside
``x = [r, v]`` and the model stays linear in the state:

    x_{k+1} = A x_k + B u_k + B U(u_k) theta,   theta_{k+1} = theta_k,   y_k = x_k + n_k

with ``U(u) = kron(I_3, u^T)`` (so that ``U(u) theta = (G - I) u``), ``u`` the thrust commanded (N) and
``y`` the navigation estimate. It is the exact Kalman filter of that model (time-varying: ``U``
moves with the thrust), with

- ``R = diag(nav_position^2 I, nav_velocity^2 I)``, the :class:`ErrorBounds`' one-sigma noise;
- the prior on ``theta`` from the bounds' one-sigma errors: ``thrust_scale^2 + mass^2`` on the
  diagonal of ``G - I`` (the two scale the thrust alike, to first order) and the misalignment angle's
  (radians) on the off-diagonal entries (a small rotation about a random axis);
- a process noise of ``PROCESS_FLOOR`` times ``R`` on ``x``: what the model leaves out (the thrust
  box clipping ``G u``, the second-order terms of the prior). Without it the filter would trust its
  model for ever and stop listening.

``sigma()`` is each row's one-sigma estimate error, from the covariance; ``noise_scale()`` checks the
model against the measurements (the innovations' normalised square, as flight software's filter
monitors do) and ``sigma()`` widens by it where the measurements are noisier than ``R`` says. The
robust CBF can size its navigation margins by ``sigma()`` (``fly(..., cbf_navigation="covariance")``).

An episode starts at its first measurement (``x`` covariance ``R``). A nominal flight (no noise, no
thrust error) sees no innovation and flies exactly as it would on the measurement.
"""

from __future__ import annotations

import numpy as np

from cwh_envs.problems import DockingProblem
from cwh_envs.robust_cbf import ErrorBounds

PROCESS_FLOOR = 1e-5  # of R, per step, on [r, v] (module docstring; 1e-3 left 50 % more position error)
_N = 15  # [r, v] and vec(G - I)
NOISE_PRIOR_STEPS = 1.0  # steps of prior at the model's noise level in noise_scale's mean


class NavigationFilter:
    """The filter of the module docstring for a batch of episodes, one row each.

    ``start(rows, measurements)`` begins those rows' episodes; ``step(thrust, measurements)`` takes
    the thrust (N, 3) N commanded since the last measurement and the new measurements (N, 6), and
    returns the estimates of ``[r, v]`` (N, 6).
    """

    def __init__(self, problem: DockingProblem, bounds: ErrorBounds) -> None:
        if not isinstance(bounds, ErrorBounds):
            raise ValueError(f"bounds must be an ErrorBounds, got {bounds!r}")
        if bounds.nav_position <= 0 or bounds.nav_velocity <= 0:
            raise ValueError(
                "a navigation filter needs the measurement's noise: ErrorBounds.nav_position and "
                f"nav_velocity must be > 0, got {bounds.nav_position!r} and {bounds.nav_velocity!r}"
            )
        self.a, self.b = problem.matrices()
        self.noise = np.diag([bounds.nav_position**2] * 3 + [bounds.nav_velocity**2] * 3)
        scale = bounds.thrust_scale**2 + bounds.mass**2
        tilt = np.radians(bounds.misalignment_deg) ** 2
        self.prior = np.where(np.eye(3, dtype=bool), scale, tilt).reshape(9)  # vec(G - I)'s variances
        self.mean = np.zeros((0, _N))
        self.covariance = np.zeros((0, _N, _N))
        self.innovation_sum = np.zeros(0)  # per row: normalised innovation squared, summed (sigma)
        self.innovation_count = np.zeros(0)

    def start(self, rows: np.ndarray, measurements: np.ndarray) -> None:
        """Begin the episodes of ``rows`` (a boolean mask over the batch) at their measurements."""
        rows = np.asarray(rows, dtype=bool)
        if len(rows) != len(self.mean):  # a new batch: every row starts
            self.mean, self.covariance = np.zeros((len(rows), _N)), np.zeros((len(rows), _N, _N))
            self.innovation_sum, self.innovation_count = np.zeros(len(rows)), np.zeros(len(rows))
            rows = np.ones(len(rows), dtype=bool)
        fresh = np.zeros((_N, _N))
        fresh[:6, :6], fresh[6:, 6:] = self.noise, np.diag(self.prior)
        self.mean[rows] = np.concatenate([measurements[rows, :6], np.zeros((rows.sum(), 9))], axis=1)
        self.covariance[rows] = fresh
        self.innovation_sum[rows], self.innovation_count[rows] = NOISE_PRIOR_STEPS * 6.0, NOISE_PRIOR_STEPS

    def step(self, thrust: np.ndarray, measurements: np.ndarray) -> np.ndarray:
        n = len(self.mean)
        thrust = np.asarray(thrust, dtype=np.float64).reshape(n, 3)
        transition = np.zeros((n, _N, _N))
        transition[:, :6, :6] = self.a
        transition[:, :6, 6:] = self.b @ np.einsum("ij,nk->nijk", np.eye(3), thrust).reshape(n, 3, 9)
        transition[:, 6:, 6:] = np.eye(9)
        mean = np.einsum("nij,nj->ni", transition, self.mean)
        mean[:, :6] += thrust @ self.b.T
        covariance = transition @ self.covariance @ transition.transpose(0, 2, 1)
        covariance[:, :6, :6] += PROCESS_FLOOR * self.noise
        # the update: the measurement is [r, v] itself (H = [I_6, 0])
        innovation = np.asarray(measurements, dtype=np.float64)[:, :6] - mean[:, :6]
        inverse = np.linalg.inv(covariance[:, :6, :6] + self.noise)
        gain = covariance[:, :, :6] @ inverse
        self.innovation_sum += np.einsum("ni,nij,nj->n", innovation, inverse, innovation)
        self.innovation_count += 1
        self.mean = mean + np.einsum("nij,nj->ni", gain, innovation)
        self.covariance = covariance - gain @ covariance[:, :6, :]
        return self.mean[:, :6].copy()

    def noise_scale(self) -> np.ndarray:
        """Each row's measured noise level (N,), in variance over the filter's model: the episode's
        mean normalised innovation squared per measured component, with NOISE_PRIOR_STEPS steps of
        prior at 1. About 1 where the measurements are as noisy as the filter was sized for, about
        ``s^2`` where they are ``s`` times noisier."""
        return self.innovation_sum / (6.0 * self.innovation_count)

    def sigma(self) -> np.ndarray:
        """Each row's one-sigma estimate error (N, 2): position (m) and velocity (m/s), each the
        square root of the largest eigenvalue of its block of the covariance (the error's standard
        deviation along its worst direction), scaled by the square root of :meth:`noise_scale`
        where that exceeds 1: a covariance computed for the noise the filter was sized for
        understates the error of noisier measurements. What a measurement-robust CBF sizes its
        margins by (:func:`cwh_envs.robust_cbf.robust_safe_actions`' ``navigation_sigma``)."""
        blocks = (self.covariance[:, :3, :3], self.covariance[:, 3:6, 3:6])
        sigma = np.sqrt(np.stack([np.linalg.eigvalsh(block)[:, -1] for block in blocks], axis=1))
        return sigma * np.sqrt(np.maximum(self.noise_scale(), 1.0))[:, None]

    def thrust_gain(self) -> np.ndarray:
        """The estimated ``G`` (N, 3, 3) of each row: the thrust delivered per thrust commanded."""
        return np.eye(3) + self.mean[:, 6:].reshape(-1, 3, 3)
