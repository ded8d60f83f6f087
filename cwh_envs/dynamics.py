"""Clohessy-Wiltshire-Hill relative motion: the one discrete model shared by everything.

The env, the experts, the CBF filter and the families' evaluation all call
:func:`cwh_matrices` with the same arguments, so they step exactly the same
``x' = A x + B u``. Forward Euler is the paper's model (Eq. cwh_disc); ``"exact"``
is the zero-order-hold discretisation, which differs from Euler by metres over these
horizons -- comparable to the 5 m keep-out, hence the single source.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

MEAN_MOTION = 1.13e-3  # rad/s, low Earth orbit
TIME_STEP = 10.0  # s
MASS = 500.0  # kg
DISCRETIZATIONS = ("euler", "exact")


def continuous_matrices(n: float = MEAN_MOTION, mass: float = MASS) -> tuple[np.ndarray, np.ndarray]:
    """A_c, B_c of Eq. (cwh_ss) for the state [x, y, z, vx, vy, vz] in LVLH."""
    _check_positive(n=n, mass=mass)
    a_c = np.zeros((6, 6))
    a_c[0:3, 3:6] = np.eye(3)
    a_c[3, 0] = 3.0 * n**2
    a_c[5, 2] = -(n**2)
    a_c[3, 4] = 2.0 * n
    a_c[4, 3] = -2.0 * n
    b_c = np.zeros((6, 3))
    b_c[3:6, :] = np.eye(3) / mass
    return a_c, b_c


def cwh_matrices(
    n: float = MEAN_MOTION,
    dt: float = TIME_STEP,
    mass: float = MASS,
    discretization: str = "euler",
) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (A, B) with x_{k+1} = A x_k + B u_k, u in newtons.

    Returned arrays are read-only copies of a cached result: callers share them safely.
    """
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"discretization must be one of {DISCRETIZATIONS}, got {discretization!r}")
    _check_positive(n=n, dt=dt, mass=mass)
    return _cached_matrices(float(n), float(dt), float(mass), discretization)


@lru_cache(maxsize=32)
def _cached_matrices(n: float, dt: float, mass: float, discretization: str) -> tuple[np.ndarray, np.ndarray]:
    a_c, b_c = continuous_matrices(n, mass)
    if discretization == "euler":
        a, b = np.eye(6) + dt * a_c, dt * b_c
    else:
        # Zero-order hold: expm of the augmented [[A_c, B_c], [0, 0]] block gives A and B at once
        # (scipy.linalg imported here: it costs a quarter of a second, the default is Euler).
        from scipy.linalg import expm

        block = np.zeros((9, 9))
        block[:6, :6], block[:6, 6:] = a_c, b_c
        phi = expm(block * dt)
        a, b = phi[:6, :6], phi[:6, 6:]
    a.setflags(write=False)
    b.setflags(write=False)
    return a, b


def apply(matrix: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``matrix @ v`` for a vector (k,) or for each row of a batch (N, k), batch-invariant.

    A BLAS product rounds a row differently with the size of the batch it sits in (measured: every
    row of a 1024 x 6 product differs in the last bits from the same row alone). einsum sums each
    row on its own, so an episode flown alone (``gym.make``) and as a row of a batch (the vector
    env, the families' evaluation) step to the same bits.
    """
    return np.einsum("ij,...j->...i", matrix, vectors)


def step(x: np.ndarray, u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """One step for a state (6,) or a batch (N, 6) with thrust (3,) or (N, 3); see :func:`apply`."""
    return apply(a, x) + apply(b, u)


def rollout(x0: np.ndarray, controls: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """States (H+1, 6) from x0 under the open-loop thrust sequence controls (H, 3)."""
    states = np.empty((controls.shape[0] + 1, 6))
    states[0] = x0
    for k, u in enumerate(controls):
        states[k + 1] = a @ states[k] + b @ u
    return states


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
