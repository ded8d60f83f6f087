"""The constrained docking SCP's convex subproblem, as one second-order-cone program (Clarabel);
also the soft-terminal experts' subproblems (the terminal state as an exact penalty).

Under a speed limit or an approach cone, each SCP iterate of :func:`cwh_envs.experts.scp_docking`
solves

    min ||U||^2  s.t.  x_{k+1} = A x_k + B u_k,  x_0 given,  x_H = (g, 0),  |U| <= u_max,
                       n_k^T r_k >= R + delta                      (keep-out, linearised)
                       ||v_k|| <= v0 + v1 m_k^T (r_k - g)          (speed limit, k = 1..H)
                       cos(theta) ||r_k - g|| <= a^T (r_k - g)     (approach cone, held steps)
                       m_k^T (r_k - g) >= radius                   (outside the port's ball, other steps)

with n_k, m_k and the held steps taken from the previous iterate (:class:`PathConstraints`). The
speed limit and the cone are second-order cones, so a conic solver takes them whole; the states
stay variables, which keeps every row sparse (the condensed form's rows are dense in U).

Why Clarabel (measured in ``benchmarks/bench_expert_solvers.py``): the alternative kept the exact
least-distance solver of the keep-out and met each cone by tangent-plane cuts, re-solving until no
point broke it. On the same subproblems the two agree to ~1e-7 of the cost, but the cuts took up to
52 s for a subproblem that Clarabel solves in tens of ms, and the whole expert up to minutes per
start. Clarabel is an interior-point solver for conic programs (Apache-2.0, Rust with Python
bindings, also a qpsolvers backend); the keep-out-only problem keeps its exact NNLS path.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import clarabel
import numpy as np
from scipy import sparse

from cwh_envs.constraints import CONE_TOLERANCE, cone_axis, cone_terms

PATH_TIGHTENING = 1e-3  # relative: v0 and the cone's half angle are solved this much tighter


class SubproblemFailed(Exception):
    """Clarabel did not solve the subproblem (infeasible, or stalled); the message says which."""


@dataclass(frozen=True)
class PathConstraints:
    """The speed limit and the approach cone of one SCP subproblem, as convex restrictions about the
    previous iterate's positions (``anchor``, (H+1, 3)).

    - The speed limit's distance term is linearised (``||r - g|| >= m^T (r - g)`` for the unit
      ``m`` of the anchor): a convex restriction the anchor meets whenever it met the limit.
    - The approach cone asks each step to be in the cone or at least ``radius`` from the port: a
      union, not convex. Each step keeps the branch its anchor was on: inside the cone (held), else
      outside the ball, linearised as the keep-out is (``m^T (r - g) >= radius``). Steps from
      ``held_from`` on are held to the cone whatever the anchor did.
    - Both are tightened by PATH_TIGHTENING, so a solution within the solver's tolerance meets the
      exact constraints.
    """

    unit: np.ndarray  # (H+1, 3): m_k
    speed: tuple[float, float] | None  # (v0, v1), tightened
    axis: np.ndarray  # (3,): a
    cosine: float  # of the tightened half angle
    held: np.ndarray  # (H+1,) bool: steps held to the cone
    away: np.ndarray  # (H+1,) bool: steps kept outside the port's ball
    radius: float  # m, the cone's radius

    @classmethod
    def about(cls, anchor, goal, problem, held_from: int, controllable: np.ndarray) -> PathConstraints:
        axis = cone_axis(goal[None])[0]
        offset = anchor - goal
        norm = np.linalg.norm(offset, axis=1, keepdims=True)
        unit = np.where(norm > 1e-9, offset / np.maximum(norm, 1e-300), axis)
        speed = None
        if problem.speed_limit is not None:
            v0, v1 = problem.speed_limit
            speed = (v0 * (1 - PATH_TIGHTENING), v1)
        steps = np.arange(len(anchor))
        held = away = np.zeros(len(anchor), bool)
        cosine, radius = 1.0, 0.0
        if problem.approach_cone is not None:
            half_angle, radius = problem.approach_cone
            # Inside as the env counts it: the solver meets the tightened cone only to its tolerance,
            # and a point on the tightened boundary flipping branch on that noise stalls the SCP.
            _, slack, _ = cone_terms(anchor, np.broadcast_to(goal, anchor.shape), problem.approach_cone)
            inside = slack >= -CONE_TOLERANCE
            cosine = float(np.cos(np.radians(half_angle * (1 - PATH_TIGHTENING))))
            held = (inside | (steps >= held_from)) & (steps >= 1)
            away = ~held & (steps >= 1) & controllable
        return cls(unit, speed, axis, cosine, held, away, float(radius))


@dataclass(frozen=True)
class Soft:
    """Exact (L1) penalty weights: ``terminal`` (6,) per component of ``x_H - (goal, 0)``, and ``path``
    per metre (m/s for the speed limit) by which any keep-out, ball, speed-limit or cone row is broken.
    Linear penalties, unlike quadratic ones, need no huge weight (which an interior-point method
    resolves poorly): where every constraint can be met and the weights exceed their multipliers,
    the answer is the constrained one."""

    terminal: np.ndarray
    path: float


def solve(
    model, x0, goal, keepout_steps, normals, radius, u_max, path: PathConstraints, soft: Soft | None = None
) -> np.ndarray:
    """Controls (3H,) minimising ``||U||^2`` under the dynamics, the terminal state ``(goal, 0)``, the
    thrust box, the keep-out half-spaces ``normals[k]^T r_k >= radius`` at ``keepout_steps`` and the
    ``path`` constraints. With ``soft`` every constraint but the dynamics and the box is an exact
    penalty instead (:class:`Soft`), so that any state has an answer. Raises
    :class:`SubproblemFailed` unless Clarabel reports it solved."""
    horizon = model.horizon
    columns = 6 * (horizon + 1) + 3 * horizon
    away = np.flatnonzero(path.away)
    speed_steps = np.arange(1, horizon + 1) if path.speed is not None else np.arange(0)
    held = np.flatnonzero(path.held)
    counts = [len(keepout_steps), len(away), len(speed_steps), len(held)]  # one slack per row or cone
    # Columns: states, controls, then with ``soft`` the terminal slacks (6) and the path slacks.
    total = columns + (6 + sum(counts) if soft else 0)
    slack_columns = np.split(columns + 6 + np.arange(sum(counts)), np.cumsum(counts)[:-1])
    equality, box = _fixed_rows(model)
    target = np.concatenate([goal, np.zeros(3)])
    equality_rhs = np.concatenate([x0, np.zeros(6 * horizon), target])
    if soft:
        equality, equality_rhs = equality[:-6], equality_rhs[:-6]
    blocks = [_widen(equality, total), _widen(box, total)]
    rhs = [equality_rhs, np.full(6 * horizon, u_max)]
    # Nonnegative rows: keep-out half-spaces, then the port's ball (each + its slack).
    blocks.append(
        _slackened(_position_rows(keepout_steps, -normals[keepout_steps], total), slack_columns[0], 1, soft)
    )
    rhs.append(np.full(len(keepout_steps), -radius))
    blocks.append(_slackened(_position_rows(away, -path.unit[away], total), slack_columns[1], 1, soft))
    rhs.append(-path.radius - path.unit[away] @ goal)
    if soft:  # the terminal slacks bound |x_H - target|; the path slacks are >= 0
        blocks.append(_penalty_rows(horizon, columns, total))
        rhs.append(np.concatenate([target, -target]))
        path_slacks = columns + 6 + np.arange(sum(counts))
        blocks.append(
            sparse.csr_matrix(
                (-np.ones(len(path_slacks)), (np.arange(len(path_slacks)), path_slacks)),
                shape=(len(path_slacks), total),
            )
        )
        rhs.append(np.zeros(len(path_slacks)))
    nonnegative = sum(block.shape[0] for block in blocks[1:])
    if path.speed is not None:  # t = v0 + v1 m^T (r_k - g) >= ||v_k||
        v0, v1 = path.speed
        unit = path.unit[speed_steps]
        blocks.append(
            _slackened(_cone_rows(speed_steps, -v1 * unit, -1.0, 3, total), slack_columns[2], 4, soft)
        )
        rhs.append(_cone_rhs(v0 - v1 * unit @ goal, np.zeros((len(speed_steps), 3))))
    if len(held):  # t = a^T (r_k - g) >= cos ||r_k - g||
        head = np.broadcast_to(-path.axis, (len(held), 3))
        blocks.append(_slackened(_cone_rows(held, head, -path.cosine, 0, total), slack_columns[3], 4, soft))
        rhs.append(
            _cone_rhs(
                np.full(len(held), -path.axis @ goal), np.broadcast_to(-path.cosine * goal, (len(held), 3))
            )
        )
    rows = sparse.vstack(blocks, format="csc")
    cones = [clarabel.ZeroConeT(equality.shape[0]), clarabel.NonnegativeConeT(nonnegative)]
    cones += [clarabel.SecondOrderConeT(4)] * (len(speed_steps) + len(held))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    cost, linear = _cost(model), np.zeros(total)
    if soft:
        cost = sparse.block_diag([cost, sparse.csc_matrix((total - columns, total - columns))], format="csc")
        linear[columns : columns + 6] = soft.terminal
        linear[columns + 6 :] = soft.path
    solver = clarabel.DefaultSolver(cost, linear, rows, np.concatenate(rhs), cones, settings)
    solution = solver.solve()
    if solution.status != clarabel.SolverStatus.Solved:
        raise SubproblemFailed(f"Clarabel: {solution.status}")
    return np.asarray(solution.x)[6 * (horizon + 1) : columns]


@lru_cache(maxsize=4)  # LinearModel hashes by identity, and the model itself is cached
def _fixed_rows(model) -> tuple[sparse.csr_matrix, sparse.csr_matrix]:
    """The rows every subproblem of one model shares: x_0, the dynamics and x_H as equalities
    (6 + 6H + 6 rows), and the thrust box as nonnegative rows (6H)."""
    horizon = model.horizon
    states, columns = 6 * (horizon + 1), 6 * (horizon + 1) + 3 * horizon
    pick = np.arange(6)
    first = sparse.csr_matrix((np.ones(6), (pick, pick)), shape=(6, columns))
    last = sparse.csr_matrix((np.ones(6), (pick, 6 * horizon + pick)), shape=(6, columns))
    # x_{k+1} - A x_k - B u_k = 0, one band of six rows per step
    shift = sparse.eye(horizon, horizon + 1, k=1)
    dynamics = sparse.hstack(
        [
            sparse.kron(shift, np.eye(6)) - sparse.kron(sparse.eye(horizon, horizon + 1), model.a),
            -sparse.kron(sparse.eye(horizon), model.b),
        ]
    )
    equality = sparse.vstack([first, dynamics, last], format="csr")
    equality.eliminate_zeros()
    identity = sparse.eye(3 * horizon)
    box = sparse.hstack([sparse.csr_matrix((6 * horizon, states)), sparse.vstack([identity, -identity])])
    return equality, box.tocsr()


def soft_box_controls(terminal: np.ndarray, gap: np.ndarray, u_max: float, terminal_weights) -> np.ndarray:
    """Controls U (n,) minimising ``1/2 ||U||^2 + sum_i w_i |terminal U - gap|_i`` within the box
    ``|U| <= u_max``: the soft-terminal rendezvous expert on the condensed model (``terminal`` is G,
    (6, n)), the same exact penalty as :func:`solve` with ``terminal_weights``."""
    size = terminal.shape[1]
    identity, slack = sparse.eye(size), -sparse.eye(6)
    rows = sparse.vstack(
        [
            sparse.hstack([identity, sparse.csr_matrix((size, 6))]),
            sparse.hstack([-identity, sparse.csr_matrix((size, 6))]),
            sparse.hstack([sparse.csr_matrix(terminal), slack]),
            sparse.hstack([sparse.csr_matrix(-terminal), slack]),
        ],
        format="csc",
    )
    rhs = np.concatenate([np.full(2 * size, u_max), gap, -gap])
    cost = sparse.diags(np.r_[np.ones(size), np.zeros(6)], format="csc")
    linear = np.r_[np.zeros(size), terminal_weights]
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    cones = [clarabel.NonnegativeConeT(len(rhs))]
    solution = clarabel.DefaultSolver(cost, linear, rows, rhs, cones, settings).solve()
    if solution.status != clarabel.SolverStatus.Solved:
        raise SubproblemFailed(f"Clarabel: {solution.status}")
    return np.clip(np.asarray(solution.x)[:size], -u_max, u_max)


def _widen(block: sparse.csr_matrix, columns: int) -> sparse.csr_matrix:
    """``block`` with zero columns appended up to ``columns``."""
    return sparse.csr_matrix((block.data, block.indices, block.indptr), shape=(block.shape[0], columns))


def _slackened(block: sparse.csr_matrix, slacks: np.ndarray, every: int, soft) -> sparse.csr_matrix:
    """``block`` with its slack added to every ``every``-th row (each row, or each cone's head):
    ``b - A x + s`` in place of ``b - A x``. Unchanged without ``soft``."""
    if not soft or len(slacks) == 0:
        return block
    heads = every * np.arange(len(slacks))
    return block + sparse.csr_matrix((-np.ones(len(slacks)), (heads, slacks)), shape=block.shape)


def _penalty_rows(horizon: int, columns: int, total: int) -> sparse.csr_matrix:
    """The 12 rows ``b - A x = s -+ (x_H - target)`` of the terminal penalty (its slacks right after
    ``columns``)."""
    pick = np.arange(6)
    terminal = sparse.csr_matrix((np.ones(6), (pick, 6 * horizon + pick)), shape=(6, total))
    slack = sparse.csr_matrix((np.ones(6), (pick, columns + pick)), shape=(6, total))
    return sparse.vstack([terminal - slack, -terminal - slack], format="csr")


@lru_cache(maxsize=4)
def _cost(model) -> sparse.csc_matrix:
    states, controls = 6 * (model.horizon + 1), 3 * model.horizon
    return sparse.diags(np.r_[np.zeros(states), np.ones(controls)], format="csc")


def _position_rows(steps, coefficients, columns) -> sparse.csr_matrix:
    """One row per step: ``coefficients[i] . r_{steps[i]}``."""
    rows = np.repeat(np.arange(len(steps)), 3)
    cols = (6 * steps[:, None] + np.arange(3)).ravel()
    return sparse.csr_matrix((np.ravel(coefficients), (rows, cols)), shape=(len(steps), columns))


def _cone_rows(steps, head, tail_scale, tail_state, columns) -> sparse.csr_matrix:
    """Four rows per step, one second-order cone each: ``head[i] . r_k`` for its first entry, then
    ``tail_scale`` times the state block at ``tail_state`` (0: r_k, 3: v_k) for the other three."""
    count = len(steps)
    base = 4 * np.arange(count)
    head_rows = np.repeat(base, 3)
    head_cols = (6 * steps[:, None] + np.arange(3)).ravel()
    tail_rows = (base[:, None] + 1 + np.arange(3)).ravel()
    tail_cols = (6 * steps[:, None] + tail_state + np.arange(3)).ravel()
    values = np.concatenate([np.ravel(head), np.full(3 * count, tail_scale)])
    return sparse.csr_matrix(
        (values, (np.concatenate([head_rows, tail_rows]), np.concatenate([head_cols, tail_cols]))),
        shape=(4 * count, columns),
    )


def _cone_rhs(head, tail) -> np.ndarray:
    return np.concatenate([np.asarray(head)[:, None], tail], axis=1).ravel()
