"""Minimum-energy optimal-control experts (paper Eqs. expert_rdzv and expert_rpo).

Both experts solve ``min sum ||u_k||^2`` over the thrust sequence U = [u_0; ...; u_{H-1}]
(3H unknowns, newtons) of the shared discrete model x_{k+1} = A x_k + B u_k, condensed: every
state is affine in U, ``x_k = A^k x_0 + sum_{j<k} A^{k-1-j} B u_j``, and the terminal state is
``x_H = A^H x_0 + G U`` with ``G = [A^{H-1} B, ..., A B, B]`` (6 x 3H).

* Fast path: without the thrust box the optimum is the minimum-norm solution of the terminal
  equality, ``U* = G^+ (x_target - A^H x_0)``. It is exact whenever it satisfies the box.
* Rendezvous, box binding: semismooth Newton on the dual (6 multipliers; KKT: U = clip(G^T nu),
  G U = gap) returns the exact optimum, or a Farkas proof of infeasibility, for all but ~0.1 % of
  starts; the rest go to the dense QP (3H unknowns, 6 equalities, native box) in proxsuite, whose
  answer is polished to machine precision on its saturation pattern. The tests check both paths
  against an independent, tightly converged proxsuite solve.
* Docking: sequential convex programming over per-step half-spaces ``n_k^T r_k >= R + delta``
  (:func:`scp_docking`); each convex subproblem is solved exactly as a least-distance program
  (one NNLS), with proxsuite's primal QP as the fallback when the thrust box binds. Under a speed
  limit or an approach cone each subproblem is one second-order-cone program instead
  (:mod:`cwh_envs.socp`, Clarabel).

Every returned trajectory is verified (terminal error, box, clearance); anything else raises
:class:`Infeasible`. Both experts take a ``warm_start`` (a previous plan's controls over the same
horizon): receding-horizon MPC (:mod:`cwh_envs.mpc`) re-solves from each state that way.

The soft-terminal experts (:func:`solve_rendezvous_soft`, :func:`soft_docking`) put the terminal
state into the cost as an exact (L1) penalty instead of an equality, and docking's path constraints
too (keep-out, speed limit, cone): they label any state, where the hard experts raise
:class:`Infeasible` (DAgger relabels the states a policy visits, some of which no thrust can bring
to the target within the box or keep outside the keep-out). Where the hard expert answers and the
weights exceed its multipliers, the soft one gives the same answer.
"""

from __future__ import annotations

import ctypes
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from proxsuite import proxqp
from scipy.optimize import nnls

from cwh_envs import socp
from cwh_envs.cbf import FALLBACK_DIRECTION
from cwh_envs.constraints import (
    CONE_TOLERANCE,
    SPEED_TOLERANCE,
    cone_axis,
    cone_terms,
    path_constrained,
    speed_margin,
)
from cwh_envs.problems import DockingProblem, RendezvousProblem

TERMINAL_TOLERANCE = 1e-6  # m and m/s, largest accepted terminal error of a docking demo
CLEARANCE_TOLERANCE = 1e-6  # m, accepted shortfall of ||r_k|| below R + delta
BOX_TOLERANCE = 1e-9  # N, accepted thrust excess over u_max (solver round-off)
SCP_MAX_ITERATIONS = 100  # 1000 screened starts: median 6, max 51
SCP_STEP_TOLERANCE = 1e-3  # m, largest position change between SCP iterates at convergence
SCP_COST_TOLERANCE = 1e-6  # relative cost change between SCP iterates at convergence
WORKING_BAND = 2.0  # m, steps this close to R + delta enter the subproblem QP up front
HALFSPACE_TOLERANCE = 1e-12  # unit-row slack counted as a violation by constraint generation
KOZ_ACTIVE_TOLERANCE = 1e-3  # m, a demo "touches" R + delta when its clearance is within this
APPROACH_SHARE = 0.25  # of the horizon: the approach cone's first iterate enters the cone this early
RENDEZVOUS_QP_EPS = 1e-6  # proxsuite only has to find the saturation pattern; the polish makes it exact
POLISH_STEPS = 5
NEWTON_STEPS = 25  # dual Newton steps before a box-binding rendezvous QP goes to proxsuite
# The soft-terminal experts' exact penalty w ||D (x_H - x*)||_1, D = diag(1, 1, 1, T, T, T): where the
# hard expert is feasible and w exceeds its terminal multipliers, the soft one is the same solution
# (tests/test_experts.py checks it); a velocity error of 1 mm/s weighs as a position error of T mm.
# Measured: rendezvous starts that ride the thrust box need w > 10 (at 10 they end up to 5 mm off),
# while the docking SOCP, with the states as variables, resolves w D = 1e5 to only ~3e-3 N.
SOFT_TERMINAL_WEIGHT = {"rendezvous": 1e3, "docking": 10.0}  # N^2 / m
SOFT_VELOCITY_SCALE = 10.0  # s
SOFT_PATH_WEIGHT = 10.0  # N^2 / m (or per m/s): the soft docking expert's price of a broken path constraint


class Infeasible(Exception):
    """The expert could not produce a verified trajectory for this start (and goal)."""


# ----------------------------------------------------------------------------- condensed model


@dataclass(frozen=True, eq=False)  # hashed by identity: instances are cached singletons
class LinearModel:
    """Condensed dynamics of one discrete model over one horizon H.

    ``powers`` (H+1, 6, 6): A^k; ``terminal`` (6, 3H): G;
    ``terminal_pinv`` (3H, 6): G^+ (minimum-norm right inverse); ``position_response`` and
    ``velocity_response`` (H+1, 3, 3H): the position and velocity rows of d x_k / d U;
    ``controllable`` (H+1,) bool: whether the thrust moves r_k at all (false for k = 0 and, under
    Euler, k = 1).
    """

    a: np.ndarray
    b: np.ndarray
    horizon: int
    powers: np.ndarray
    terminal: np.ndarray
    terminal_pinv: np.ndarray
    position_response: np.ndarray
    velocity_response: np.ndarray
    controllable: np.ndarray

    def terminal_gap(self, x0: np.ndarray, target: np.ndarray) -> np.ndarray:
        """``x_target - A^H x_0`` for (6,) or (N, 6) inputs: what U must add to the coasting state."""
        return target - x0 @ self.powers[-1].T

    def min_energy(self, x0: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Unconstrained minimum-energy controls (..., 3H) reaching ``target`` from ``x0``."""
        return self.terminal_gap(x0, target) @ self.terminal_pinv.T

    def positions(self, x0: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """Positions (H+1, 3) from x0 (6,) under controls (3H,)."""
        return self.powers[:, :3, :] @ x0 + self.position_response @ controls

    def rollout(self, x0: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """States (..., H+1, 6) from x0 (..., 6) under controls (..., 3H) or (..., H, 3)."""
        controls = (
            controls.reshape(*controls.shape[:-1], self.horizon, 3) if controls.shape[-1] != 3 else controls
        )
        states = np.empty((*x0.shape[:-1], self.horizon + 1, 6))
        states[..., 0, :] = x0
        for k in range(self.horizon):
            states[..., k + 1, :] = states[..., k, :] @ self.a.T + controls[..., k, :] @ self.b.T
        return states


def linear_model(problem: RendezvousProblem | DockingProblem) -> LinearModel:
    """The cached condensed model for a problem's dynamics and horizon."""
    return _linear_model(problem.n, problem.dt, problem.mass, problem.discretization, problem.horizon)


@lru_cache(maxsize=16)
def _linear_model(n: float, dt: float, mass: float, discretization: str, horizon: int) -> LinearModel:
    a, b = RendezvousProblem(n=n, dt=dt, mass=mass, discretization=discretization).matrices()
    powers = np.empty((horizon + 1, 6, 6))
    powers[0] = np.eye(6)
    for k in range(horizon):
        powers[k + 1] = a @ powers[k]
    impulse = powers[:-1] @ b  # A^k B
    terminal = np.concatenate(impulse[::-1], axis=1)
    lag = np.arange(horizon + 1)[:, None] - 1 - np.arange(horizon)[None, :]  # k - 1 - j
    response = np.where((lag >= 0)[:, :, None, None], impulse[np.clip(lag, 0, None)], 0.0)  # (H+1, H, 6, 3)
    state_response = response.transpose(0, 2, 1, 3).reshape(horizon + 1, 6, 3 * horizon)
    position_response = np.ascontiguousarray(state_response[:, :3])
    velocity_response = np.ascontiguousarray(state_response[:, 3:])
    controllable = np.any(position_response != 0.0, axis=(1, 2))
    arrays = [powers, terminal, np.linalg.pinv(terminal), position_response, velocity_response, controllable]
    for array in arrays:
        array.setflags(write=False)
    return LinearModel(a, b, horizon, *arrays)


def resolve_problem(kind: type, problem=None, **params):
    """``problem`` (default ``kind()``) with ``params`` replaced; a wrong problem type is an error."""
    problem = kind() if problem is None else problem
    if not isinstance(problem, kind):
        raise ValueError(f"problem must be a {kind.__name__}, got {type(problem).__name__}")
    return problem.replace(**params) if params else problem


def _as_vector(name: str, value, size: int) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (size,):
        raise ValueError(f"{name} must be a finite vector of shape ({size},), got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be a finite vector of shape ({size},), got one with NaN/inf entries")
    return array


@contextmanager
def serial_openmp():
    """Run proxsuite single-threaded: its OpenMP (Eigen) threads cost 2-3x on these small QPs
    whenever the cores are shared (vector envs, training). Restores the previous setting."""
    runtime = _openmp_runtime()
    if runtime is None:
        yield
        return
    previous = runtime.omp_get_max_threads()
    runtime.omp_set_num_threads(1)
    try:
        yield
    finally:
        runtime.omp_set_num_threads(previous)


@lru_cache(maxsize=1)
def _openmp_runtime():
    for name in ("libgomp.so.1", "libomp.so", "libomp.dylib", "libiomp5.so"):
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    return None


# ----------------------------------------------------------------------------------- rendezvous


def solve_rendezvous(
    x0, problem: RendezvousProblem | None = None, *, warm_start=None, **params
) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-energy rendezvous to the origin (Eq. expert_rdzv) from x0 (6,) [m, m/s].

    ``params`` override fields of ``problem`` (default ``RendezvousProblem()``). Returns states
    (H+1, 6) and controls (H, 3) [N]. Raises :class:`Infeasible` when no box-feasible thrust
    brings every state component to within ``reach_tolerance`` of zero. ``warm_start`` (controls
    (H, 3) or (3H,)): when the box binds, its saturation pattern is tried first, which settles the
    exact optimum in one linear solve when the pattern still holds (else the cold path runs).
    """
    problem = resolve_problem(RendezvousProblem, problem, **params)
    x0 = _as_vector("x0", x0, 6)
    model = linear_model(problem)
    gap = model.terminal_gap(x0, np.zeros(6))
    controls = model.terminal_pinv @ gap
    if np.abs(controls).max() > problem.u_max:
        exact = None
        if warm_start is not None:
            warm = _as_vector("warm_start", np.ravel(warm_start), 3 * problem.horizon)
            exact = _kkt_point(model.terminal, gap, warm, problem.u_max)
        if exact is None:
            exact = _box_constrained_controls(model, gap, controls, problem.u_max)
        controls = exact
    return _verified(model, x0, controls, np.zeros(6), problem.u_max, problem.reach_tolerance)


def solve_rendezvous_soft(
    x0, problem: RendezvousProblem | None = None, **params
) -> tuple[np.ndarray, np.ndarray]:
    """The soft-terminal rendezvous expert: ``min 1/2 sum ||u_k||^2 + w ||D x_H||_1`` within the
    thrust box (module docstring), one convex program (:func:`cwh_envs.socp.soft_box_controls`),
    polished on its saturation pattern as the hard expert's QP answers are. Any start has an
    answer; where :func:`solve_rendezvous` has one too, it is the same. Returns states (H+1, 6) and
    controls (H, 3) [N]; ``states[-1]`` says how far from the origin it ends. Raises
    :class:`Infeasible` only when the solver fails."""
    problem = resolve_problem(RendezvousProblem, problem, **params)
    x0 = _as_vector("x0", x0, 6)
    model = linear_model(problem)
    gap = model.terminal_gap(x0, np.zeros(6))
    try:
        controls = socp.soft_box_controls(model.terminal, gap, problem.u_max, _soft_weights("rendezvous"))
    except socp.SubproblemFailed as error:
        raise Infeasible(f"soft-terminal rendezvous: {error}") from error
    # Where the target is met, the exact optimum is the hard expert's KKT point on this pattern.
    exact = _kkt_point(model.terminal, gap, controls, problem.u_max)
    if exact is not None:
        controls = exact
    return model.rollout(x0, controls), controls.reshape(problem.horizon, 3)


def _soft_weights(task: str) -> np.ndarray:
    """w D of the soft-terminal penalty, per terminal component (m, then m/s)."""
    return SOFT_TERMINAL_WEIGHT[task] * np.r_[np.ones(3), np.full(3, SOFT_VELOCITY_SCALE)]


def solve_rendezvous_many(x0s, problem: RendezvousProblem | None = None) -> tuple[np.ndarray, ...]:
    """Batched :func:`solve_rendezvous` over starts (N, 6), same results.

    Returns states (N, H+1, 6), controls (N, H, 3) [N] and ``solved`` (N,) bool; the rows of
    unsolved starts are NaN. The fast path for the whole batch is one matrix product.
    """
    problem = resolve_problem(RendezvousProblem, problem)
    x0s = np.asarray(x0s, dtype=np.float64)
    if x0s.ndim != 2 or x0s.shape[1] != 6:
        raise ValueError(f"x0s must have shape (N, 6), got {x0s.shape}")
    model = linear_model(problem)
    gaps = model.terminal_gap(x0s, np.zeros(6))
    controls = gaps @ model.terminal_pinv.T
    solved = np.ones(len(x0s), dtype=bool)
    for i in np.flatnonzero(np.abs(controls).max(axis=1, initial=0.0) > problem.u_max):
        try:
            controls[i] = _box_constrained_controls(model, gaps[i], controls[i], problem.u_max)
        except Infeasible:
            solved[i] = False
    states = model.rollout(x0s, controls)
    solved &= np.abs(states[:, -1]).max(axis=1) <= problem.reach_tolerance
    solved &= np.abs(controls).max(axis=1, initial=0.0) <= problem.u_max + BOX_TOLERANCE
    states[~solved] = np.nan
    controls[~solved] = np.nan
    return states, controls.reshape(len(x0s), problem.horizon, 3), solved


def _box_constrained_controls(model: LinearModel, gap: np.ndarray, free_optimum: np.ndarray, u_max: float):
    """``argmin ||U||^2 s.t. G U = gap, |U| <= u_max`` (3H,) when the box binds; raises :class:`Infeasible`.

    Semismooth Newton on the 6 equality multipliers (:func:`_dual_newton`) settles all but ~0.1 %
    of the starts in a few steps, with the exact optimum or a proof of infeasibility; proxsuite
    (dense, native box) solves the rest and :func:`_polish_box_solution` makes its answer exact.
    """
    verdict, controls = _dual_newton(model.terminal, gap, model.terminal_pinv.T @ free_optimum, u_max)
    if verdict == "unreachable":
        raise Infeasible("rendezvous start certified unreachable (Farkas)")
    if verdict == "optimal":
        return controls
    # A fresh QP per solve (rare: ~0.1 % of starts) keeps the answer independent of solve order.
    size = 3 * model.horizon
    qp = proxqp.dense.QP(size, 6, 0, box_constraints=True)
    qp.settings.eps_abs = RENDEZVOUS_QP_EPS
    qp.settings.eps_rel = 0.0
    qp.settings.max_iter = 1000
    limit = np.full(size, u_max)
    qp.init(np.eye(size), np.zeros(size), model.terminal, gap, None, None, None, -limit, limit)
    with serial_openmp():
        qp.solve()
    if qp.results.info.status != proxqp.QPSolverOutput.PROXQP_SOLVED:
        raise Infeasible(f"rendezvous QP: {qp.results.info.status.name}")
    return _polish_box_solution(model.terminal, gap, qp.results.x.copy(), u_max)


def _dual_newton(g: np.ndarray, gap: np.ndarray, nu: np.ndarray, u_max: float):
    """Damped semismooth Newton ascent on the dual of ``min 1/2 ||U||^2, G U = gap, |U| <= u_max``.

    The dual ``q(nu) = nu^T gap - sum_j huber(g_j^T nu)`` is concave with gradient
    ``gap - G clip(G^T nu)``; the KKT conditions are ``U = clip(G^T nu)`` and ``G U = gap``. Returns

    * ``("optimal", U)`` once the gradient vanishes: U is then polished on its saturation pattern
      (:func:`_polish_box_solution`), i.e. exact to round-off;
    * ``("unreachable", None)`` with a Farkas certificate: a box-feasible U with G U = gap gives
      ``nu^T gap = (G^T nu)^T U <= u_max ||G^T nu||_1`` for every nu, so an iterate violating
      that proves infeasibility (q is unbounded then and the iterates turn towards one);
    * ``("undecided", None)`` after NEWTON_STEPS steps.

    ``nu`` starts at ``(G G^T)^{-1} gap``, where ``G^T nu`` is the unconstrained optimum.
    """
    for _ in range(NEWTON_STEPS):
        slopes = g.T @ nu
        if nu @ gap > u_max * np.abs(slopes).sum() * (1.0 + 1e-9):
            return "unreachable", None
        controls = np.clip(slopes, -u_max, u_max)
        ascent = gap - g @ controls
        if np.abs(ascent).max() <= 1e-10 * np.abs(gap).max():
            return "optimal", _polish_box_solution(g, gap, controls, u_max)
        free = np.abs(slopes) < u_max
        curvature = g[:, free] @ g[:, free].T + 1e-12 * np.trace(g @ g.T) * np.eye(6)
        step = np.linalg.solve(curvature, ascent)
        value, rate = _dual_value(g, gap, nu, u_max), 1e-4 * (ascent @ step)
        scale = 1.0
        while _dual_value(g, gap, nu + scale * step, u_max) < value + scale * rate and scale > 1e-6:
            scale *= 0.5
        nu = nu + scale * step
    return "undecided", None


def _dual_value(g: np.ndarray, gap: np.ndarray, nu: np.ndarray, u_max: float) -> float:
    slopes = np.abs(g.T @ nu)
    huber = np.where(slopes <= u_max, 0.5 * slopes**2, u_max * slopes - 0.5 * u_max**2)
    return nu @ gap - huber.sum()


def _polish_box_solution(g: np.ndarray, gap: np.ndarray, approx: np.ndarray, u_max: float) -> np.ndarray:
    """The exact KKT point ``U = clip(G^T nu), G U = gap``, found from the saturation pattern of ``approx``.

    For a pattern (saturated set S with signs, free set F) nu solves ``G_F G_F^T nu = gap - G_S U_S``;
    the pattern is optimal when ``clip(G^T nu)`` reproduces it. Otherwise the pattern is updated to
    that of ``G^T nu`` (a primal-dual active-set / semismooth Newton step, which converges in one or
    two steps from the solver's answer). If it does not settle, the solver's tolerance-level answer
    is returned and left to the terminal-error check.
    """
    exact = _kkt_point(g, gap, approx, u_max)
    return np.clip(approx, -u_max, u_max) if exact is None else exact


def _kkt_point(g: np.ndarray, gap: np.ndarray, approx: np.ndarray, u_max: float) -> np.ndarray | None:
    """The KKT point of :func:`_polish_box_solution` from the saturation pattern of ``approx``, or
    None when the pattern does not settle within POLISH_STEPS."""
    pattern = np.where(np.abs(approx) >= u_max * (1.0 - 1e-6), np.sign(approx), 0.0)
    for _ in range(POLISH_STEPS):
        free = pattern == 0.0
        try:
            nu = np.linalg.solve(g[:, free] @ g[:, free].T, gap - g[:, ~free] @ (u_max * pattern[~free]))
        except np.linalg.LinAlgError:
            return None
        unclipped = g.T @ nu
        new_pattern = np.where(np.abs(unclipped) > u_max, np.sign(unclipped), 0.0)
        if np.array_equal(new_pattern, pattern):
            return np.where(free, unclipped, u_max * pattern)
        pattern = new_pattern
    return None


def _verified(model, x0, controls, target, u_max, tolerance) -> tuple[np.ndarray, np.ndarray]:
    states = model.rollout(x0, controls)
    error = np.abs(states[-1] - target).max()
    if not error <= tolerance:
        raise Infeasible(f"terminal error {error:.3g} exceeds {tolerance:.3g}")
    excess = np.abs(controls).max() - u_max
    if excess > BOX_TOLERANCE:
        raise Infeasible(f"thrust exceeds u_max by {excess:.3g} N")
    return states, controls.reshape(model.horizon, 3)


# -------------------------------------------------------------------------------------- docking


class DockingSolution(NamedTuple):
    """An SCP docking solution: states (H+1, 6), controls (H, 3) [N], SCP iterations, cost [N^2]."""

    states: np.ndarray
    controls: np.ndarray
    iterations: int
    cost: float


def solve_docking(
    x0, goal, problem: DockingProblem | None = None, *, warm_start=None, **params
) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-energy docking around the keep-out (Eq. expert_rpo) from x0 (6,) to goal (3,) [m].

    Returns states (H+1, 6) and controls (H, 3) [N]; raises :class:`Infeasible` unless the SCP
    converges to a trajectory with terminal error <= 1e-6, thrust in the box and
    ``||r_k|| >= R + delta - 1e-6`` at every step.
    """
    solution = scp_docking(x0, goal, problem, warm_start=warm_start, **params)
    return solution.states, solution.controls


def scp_docking(
    x0, goal, problem: DockingProblem | None = None, *, warm_start=None, **params
) -> DockingSolution:
    """:func:`solve_docking` with the SCP diagnostics.

    Iterate i solves the convex subproblem with half-spaces ``n_k^T r_k >= R + delta`` where
    ``n_k = r_k / ||r_k||`` of iterate i-1 (iterate 0: the unconstrained minimum-energy path, or
    ``warm_start``, controls (H, 3) or (3H,) of a previous plan over the same horizon).
    Since ``||r|| >= n^T r`` for a unit n, every subproblem solution clears the sphere, and the
    previous iterate (once feasible) stays feasible for the next subproblem, so the cost never
    rises after the first iterate. Stops when both the largest position change and the relative
    cost change fall below tolerance.
    """
    problem = resolve_problem(DockingProblem, problem, **params)
    model, x0, goal, target, gap, radius = _docking_setup(x0, goal, problem)
    positions = model.positions(x0, model.terminal_pinv @ gap)
    shortfall = radius - np.linalg.norm(positions[~model.controllable], axis=1).min()
    if shortfall > CLEARANCE_TOLERANCE:
        raise Infeasible(f"a position no thrust can move (k = 0, Euler k = 1) is {shortfall:.3g} m inside")
    controls, iteration = _run_scp(model, x0, goal, gap, radius, problem, warm_start, soft=False)
    cost = controls @ controls
    states, controls = _verified(model, x0, controls, target, problem.u_max, TERMINAL_TOLERANCE)
    shortfall = radius - np.linalg.norm(states[:, :3], axis=1).min()
    if shortfall > CLEARANCE_TOLERANCE:
        raise Infeasible(f"trajectory enters the keep-out margin by {shortfall:.3g} m")
    _verify_path_constraints(states, goal, problem)
    return DockingSolution(states, controls, iteration, float(cost))


def soft_docking(
    x0, goal, problem: DockingProblem | None = None, *, warm_start=None, **params
) -> DockingSolution:
    """The soft-terminal docking expert: the SCP of :func:`scp_docking` with every subproblem one SOCP
    (:mod:`cwh_envs.socp`) in which the terminal state and every path constraint (keep-out, speed
    limit, approach cone) are exact penalties (module docstring). It answers from states the hard
    expert cannot (one already in the keep-out's margin, or off the cone); where both answer, they
    agree. ``states[-1]`` says how far from the docking state it ends. Raises :class:`Infeasible`
    only when the SCP itself fails."""
    problem = resolve_problem(DockingProblem, problem, **params)
    model, x0, goal, _, gap, radius = _docking_setup(x0, goal, problem)
    controls, iteration = _run_scp(model, x0, goal, gap, radius, problem, warm_start, soft=True)
    excess = np.abs(controls).max() - problem.u_max
    if excess > BOX_TOLERANCE:
        raise Infeasible(f"thrust exceeds u_max by {excess:.3g} N")
    controls = np.clip(controls, -problem.u_max, problem.u_max)
    return DockingSolution(
        model.rollout(x0, controls), controls.reshape(-1, 3), iteration, float(controls @ controls)
    )


def _docking_setup(x0, goal, problem: DockingProblem):
    x0 = _as_vector("x0", x0, 6)
    goal = _as_vector("goal", goal, 3)
    radius = problem.koz_radius + problem.margin
    if np.linalg.norm(goal) < radius:
        raise ValueError(f"goal {goal} lies inside the keep-out radius plus margin ({radius} m)")
    model = linear_model(problem)
    target = np.concatenate([goal, np.zeros(3)])
    return model, x0, goal, target, model.terminal_gap(x0, target), radius


def _run_scp(model, x0, goal, gap, radius, problem, warm_start, soft: bool) -> tuple[np.ndarray, int]:
    """Every SCP stage from the first iterate: (controls (3H,), iterations in all).

    A warm start is a plan that already has its final shape, so it goes straight to the whole
    problem; a cold start begins with the approach cone's waypoint path (if any), and the speed
    limit, linearised about the previous iterate, joins only after the keep-out and the cone have
    converged on their own (sound only once the path has its final shape)."""
    if warm_start is not None:
        controls = _as_vector("warm_start", np.ravel(warm_start), 3 * model.horizon)
        stages = [problem]
    else:
        controls = model.terminal_pinv @ gap
        if problem.approach_cone is not None:  # start from a path that already arrives along the axis
            controls = _waypoint_controls(model, x0, gap, goal, problem.approach_cone[1])
        stages = (
            [problem.replace(speed_limit=None), problem] if problem.speed_limit is not None else [problem]
        )
    positions = model.positions(x0, controls)
    iteration = 0
    for stage in stages:
        controls, positions, iterations = _scp(model, x0, goal, gap, radius, stage, controls, positions, soft)
        iteration += iterations
    return controls, iteration


def _scp(
    model, x0, goal, gap, radius, problem, controls, positions, soft
) -> tuple[np.ndarray, np.ndarray, int]:
    """SCP iterations from ``controls`` (their ``positions``) to convergence: (controls, positions,
    iterations)."""
    cost = controls @ controls
    for iteration in range(1, SCP_MAX_ITERATIONS + 1):
        if soft or path_constrained(problem):
            controls = _path_subproblem(model, x0, goal, positions, radius, problem, soft)
        else:
            controls = _halfspace_subproblem(model, x0, gap, positions, radius, problem.u_max)
        new_positions = model.positions(x0, controls)
        new_cost = controls @ controls
        step = np.linalg.norm(new_positions - positions, axis=1).max()
        converged = step <= SCP_STEP_TOLERANCE and abs(new_cost - cost) <= SCP_COST_TOLERANCE * new_cost
        positions, cost = new_positions, new_cost
        if converged:
            return controls, positions, iteration
    raise Infeasible(f"SCP did not converge in {SCP_MAX_ITERATIONS} iterations (last step {step:.3g} m)")


def _waypoint_controls(model, x0, gap, goal, distance) -> np.ndarray:
    """Minimum-energy controls reaching the goal that pass, APPROACH_SHARE of the horizon before its
    end, the point ``distance`` out along the docking axis: the first SCP iterate of an approach
    cone. The keep-out's half-spaces are linearised about the iterate, so an iterate that arrives
    from the chief's side (as the unconstrained path does) would wall the cone off for good."""
    step = _approach_step(model)
    waypoint = goal + distance * cone_axis(goal[None])[0]
    rows = np.concatenate([model.terminal, model.position_response[step]])
    rhs = np.concatenate([gap, waypoint - model.powers[step, :3, :] @ x0])
    return np.linalg.lstsq(rows, rhs, rcond=None)[0]


def _approach_step(model) -> int:
    return model.horizon - int(np.ceil(APPROACH_SHARE * model.horizon))


def _verify_path_constraints(states: np.ndarray, goal: np.ndarray, problem: DockingProblem) -> None:
    """Raise Infeasible unless the states x_1..x_H meet the speed limit and the approach cone as
    the env counts them (cwh_envs.constraints, with its tolerances)."""
    after, goals = states[1:], np.broadcast_to(goal, (len(states) - 1, 3))
    if problem.speed_limit is not None:
        worst = speed_margin(after, goals, problem.speed_limit).min()
        if worst < -SPEED_TOLERANCE:
            raise Infeasible(f"trajectory exceeds the speed limit by {-worst:.3g} m/s")
    if problem.approach_cone is not None:
        region, slack, _ = cone_terms(after, goals, problem.approach_cone)
        if np.any(region & (slack < -CONE_TOLERANCE)):
            raise Infeasible(f"trajectory leaves the approach cone by {-slack[region].min():.3g} m")


def koz_active(states: np.ndarray, problem: DockingProblem, tolerance: float = KOZ_ACTIVE_TOLERANCE):
    """Whether trajectories (H+1, 6) or (N, H+1, 6) touch ``R + delta`` within ``tolerance`` [m]."""
    clearance = np.linalg.norm(np.asarray(states)[..., :3], axis=-1).min(axis=-1)
    return clearance <= problem.koz_radius + problem.margin + tolerance


def _halfspace_subproblem(model, x0, gap, positions, radius, u_max) -> np.ndarray:
    """Controls (3H,) of ``min ||U||^2 s.t. G U = gap, n_k^T r_k >= radius (k = 1..H-1), |U| <= u_max``.

    Constraint generation: only the steps within WORKING_BAND of the sphere enter the QP; any
    other step the solution violates is added and the QP re-solved, so the result solves the full
    subproblem. The box almost never binds (u_max = 2 N against ~0.2 N), so the exact box-free
    solve runs first and proxsuite's primal QP with the box is the fallback.
    """
    normals = _keepout_normals(positions)
    rows = np.einsum("ki,kij->kj", normals, model.position_response)
    rhs = radius - np.einsum("ki,kij,j->k", normals, model.powers[:, :3, :], x0)
    constrained = _keepout_steps(model)
    working = constrained & (np.linalg.norm(positions, axis=1) < radius + WORKING_BAND)
    for _ in range(model.horizon):
        controls = _min_norm_with_halfspaces(model, gap, rows[working], rhs[working])
        if np.abs(controls).max() > u_max:
            controls = _primal_box_qp(model.terminal, gap, rows[working], rhs[working], u_max)
        violated = constrained & ~working & (rows @ controls - rhs < -HALFSPACE_TOLERANCE)
        if not violated.any():
            return controls
        working |= violated
    raise Infeasible("constraint generation did not settle")


def _path_subproblem(model, x0, goal, positions, radius, problem: DockingProblem, soft: bool) -> np.ndarray:
    """The subproblem under the speed limit or the approach cone, or of the soft-terminal expert: one
    second-order-cone program with every keep-out half-space (:mod:`cwh_envs.socp`)."""
    path = socp.PathConstraints.about(positions, goal, problem, _approach_step(model), model.controllable)
    keepout = model.controllable if soft else _keepout_steps(model)  # soft: x_H is not pinned to g
    penalties = socp.Soft(_soft_weights("docking"), SOFT_PATH_WEIGHT) if soft else None
    steps = np.flatnonzero(keepout)
    try:
        return socp.solve(
            model, x0, goal, steps, _keepout_normals(positions), radius, problem.u_max, path, penalties
        )
    except socp.SubproblemFailed as error:
        raise Infeasible(f"constrained subproblem: {error}") from error


def _keepout_normals(positions: np.ndarray) -> np.ndarray:
    """Unit n_k = r_k / ||r_k|| (H+1, 3) of the iterate's positions."""
    distances = np.linalg.norm(positions, axis=1)
    # A position exactly at the centre has no radial direction; any unit vector is a valid restriction.
    return np.where(
        distances[:, None] > 0.0, positions / np.maximum(distances, 1e-300)[:, None], FALLBACK_DIRECTION
    )


def _keepout_steps(model) -> np.ndarray:
    """(H+1,) bool: the steps a subproblem holds outside the keep-out."""
    constrained = model.controllable.copy()  # the others were checked once in scp_docking
    constrained[-1] = False  # the goal, outside R + delta by validation
    return constrained


def _min_norm_with_halfspaces(model, gap, rows, rhs) -> np.ndarray:
    """``argmin ||U|| s.t. G U = gap, rows U >= rhs``, exactly, by least-distance programming.

    The minimum-norm solution of the equalities, ``U_p = G^+ gap``, is orthogonal to the null space
    of G, so ``U = U_p + w`` with w the least-distance point of ``P rows w >= rhs - rows U_p``
    (P = I - G^+ G); that LDP is solved through one NNLS (Lawson & Hanson, ch. 23), an exact
    active-set method that copes with the nearly parallel rows of consecutive hugging steps.
    """
    particular = model.terminal_pinv @ gap
    if len(rhs) == 0:
        return particular
    projected = rows - (rows @ model.terminal_pinv) @ model.terminal
    lift = rhs - rows @ particular
    scale = 1.0 / np.linalg.norm(projected, axis=1)
    projected, lift = projected * scale[:, None], lift * scale
    size = projected.shape[1]
    stacked = np.concatenate([projected.T, lift[None, :]])  # (3H + 1, m)
    target = np.zeros(size + 1)
    target[-1] = 1.0
    try:
        weights, _ = nnls(stacked, target)
    except RuntimeError as error:  # iteration limit
        raise Infeasible(f"half-space subproblem: {error}") from error
    residual = stacked @ weights - target
    if residual[-1] > -1e-12:
        raise Infeasible("half-space subproblem is infeasible")
    return particular - residual[:-1] / residual[-1]


def _primal_box_qp(eq_rows, eq_rhs, rows, rhs, u_max) -> np.ndarray:
    size = eq_rows.shape[1]
    qp = proxqp.dense.QP(size, len(eq_rhs), len(rhs), box_constraints=True)
    qp.settings.eps_abs = 1e-9
    qp.settings.eps_rel = 0.0
    qp.settings.max_iter = 200  # solved ones take ~15; an infeasible one would grind for minutes
    limit = np.full(size, u_max)
    qp.init(
        np.eye(size), np.zeros(size), eq_rows, eq_rhs, rows, rhs, np.full(len(rhs), np.inf), -limit, limit
    )
    with serial_openmp():
        qp.solve()
    if qp.results.info.status != proxqp.QPSolverOutput.PROXQP_SOLVED:
        raise Infeasible(f"docking QP with the thrust box: {qp.results.info.status.name}")
    return np.clip(qp.results.x, -u_max, u_max)
