"""A family's trained docking policy, compiled (numba) for one chaser: its MLP and the closed-form
law it corrects, as one function of the observation.

The ONNX export (:mod:`cwh_envs.onnx_policy`) of the constrained family's route form is an 88-node
graph once onnxruntime has optimised it, most of its nodes the route law's, and costs about 60 µs a
step on one chaser (measured alone: benchmarks/bench_flight_path.py), as much as the compiled
filter and the navigation filter together, twice over. :class:`CompiledPolicy` computes the same function with
loops that numba compiles once (cached on disk), in float64:

    action = clip(law(obs) + scale * tanh(net(z)) * [m > correction_above], -1, 1)   # residual forms
    action = clip(net(z), -1, 1)                                                   # no law
    z = (obs - obs_mean) / obs_std,  m = round(tau H) clamped to [1, H]

``net`` is the MLP (linear layers with ``activation`` between them; dropout is off in flight), and
``law(obs) = (K_m t - L_m [r, v]) / u_max`` with ``t`` the goal g ("goal": the minimum-energy law) or
the route's waypoint positions, g and a zero velocity ("route": :class:`cwh_envs.controllers.WaypointFeedback`,
each waypoint at ``g + along * axis + across * side`` in the plane of the docking axis and the
chaser). The observation is the docking one, ``[r (3), v (3), g (3), tau]``.

A family's export.py writes one with ``--compiled policy.npz`` and holds it to its torch policy on
1024 observations before keeping it (:func:`compile_checked`); :meth:`CompiledPolicy.load` reads it back:

    from cwh_envs.compiled_policy import CompiledPolicy

    policy = CompiledPolicy.load("policy.npz")
    action = policy(obs)          # (10,) -> (3,), or (N, 10) -> (N, 3): thrust / u_max in [-1, 1]

numba is an optional dependency (``pip install 'cwh-autoresearch[fast]'``).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

try:
    from numba import njit
except ModuleNotFoundError as err:
    raise ModuleNotFoundError(
        "cwh_envs.compiled_policy needs numba, which is not installed: pip install 'cwh-autoresearch[fast]'",
        name=err.name,
    ) from err

from cwh_envs.controllers import AXIS_TOLERANCE
from cwh_envs.observations import DOCKING_OBS_DIM

ACTIVATIONS = ("tanh", "relu", "gelu")  # gelu: the exact (erf) form, torch.nn.GELU's default
_TORCH_ACTIVATIONS = {"Tanh": "tanh", "ReLU": "relu", "GELU": "gelu"}  # torch.nn class -> ours
FORMAT = "cwh-compiled-policy/1"  # the .npz's "format" entry; a reader refuses any other


def _array(value, name: str, ndim: int) -> np.ndarray:
    out = np.ascontiguousarray(value, dtype=np.float64)
    if out.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {out.shape}")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{name} must be finite, got NaN/inf entries")
    return out


@dataclass(frozen=True)
class ResidualLaw:
    """The closed-form law a residual policy corrects (module docstring).

    ``target_gain`` (H+1, 3, T) and ``state_gain`` (H+1, 3, 6) are the law's gain tables indexed by
    steps to go; T = 3 for the goal law, 3W + 6 for a route of W waypoints, whose positions
    ``route_along`` and ``route_across`` (W,) then give in metres. ``scale`` bounds the correction
    (a fraction of u_max); the correction is applied while the steps to go exceed
    ``correction_above`` (-1: always)."""

    scale: float
    target_gain: np.ndarray
    state_gain: np.ndarray
    u_max: float
    route_along: np.ndarray = field(default_factory=lambda: np.zeros(0))
    route_across: np.ndarray = field(default_factory=lambda: np.zeros(0))
    correction_above: int = -1

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: the checked arrays replace the given ones
        set_(self, "target_gain", _array(self.target_gain, "target_gain", 3))
        set_(self, "state_gain", _array(self.state_gain, "state_gain", 3))
        set_(self, "route_along", _array(self.route_along, "route_along", 1))
        set_(self, "route_across", _array(self.route_across, "route_across", 1))
        rows = self.target_gain.shape[0]
        if rows < 2 or self.target_gain.shape[1] != 3 or self.state_gain.shape != (rows, 3, 6):
            raise ValueError(
                f"the gain tables must be (H+1, 3, T) and (H+1, 3, 6) with H >= 1, got "
                f"{self.target_gain.shape} and {self.state_gain.shape}"
            )
        waypoints = len(self.route_along)
        if len(self.route_across) != waypoints:
            raise ValueError(
                f"route_along and route_across must have one entry per waypoint, got "
                f"{waypoints} and {len(self.route_across)}"
            )
        expected = 3 * waypoints + 6 if waypoints else 3
        if self.target_gain.shape[2] != expected:
            raise ValueError(
                f"target_gain has {self.target_gain.shape[2]} columns; {waypoints} waypoints need {expected}"
            )
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale must be finite and > 0, got {self.scale!r}")
        if not (math.isfinite(self.u_max) and self.u_max > 0):
            raise ValueError(f"u_max must be finite and > 0 N, got {self.u_max!r}")
        if not (isinstance(self.correction_above, int | np.integer) and -1 <= self.correction_above < rows):
            raise ValueError(f"correction_above must be an int in [-1, H], got {self.correction_above!r}")

    @property
    def horizon(self) -> int:
        return self.target_gain.shape[0] - 1


class CompiledPolicy:
    """An MLP (``weights[i]`` (out, in), ``biases[i]`` (out,), ``activation`` between the layers) on
    standardised docking observations, optionally a bounded correction to ``law`` (module docstring).

    ``metadata``: what :meth:`save` wrote with it ({} for one built here). One caller at a time: a
    call works in the instance's own scratch rows."""

    def __init__(self, weights, biases, activation: str, obs_mean, obs_std, law: ResidualLaw | None = None):
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {list(ACTIVATIONS)}, got {activation!r}")
        weights = [_array(w, f"weights[{i}]", 2) for i, w in enumerate(weights)]
        biases = [_array(b, f"biases[{i}]", 1) for i, b in enumerate(biases)]
        if not weights or len(weights) != len(biases):
            raise ValueError(
                f"one bias per weight matrix, at least one layer: got {len(weights)} and {len(biases)}"
            )
        width = DOCKING_OBS_DIM
        for i, (w, b) in enumerate(zip(weights, biases, strict=True)):
            if w.shape[1] != width or b.shape != (w.shape[0],):
                raise ValueError(
                    f"layer {i}: weights {w.shape} and bias {b.shape} do not follow a layer of width {width}"
                )
            width = w.shape[0]
        if width != 3:
            raise ValueError(f"the last layer must output the 3 thrust axes, got {width}")
        self.obs_mean = _array(obs_mean, "obs_mean", 1)
        self.obs_std = _array(obs_std, "obs_std", 1)
        if self.obs_mean.shape != (DOCKING_OBS_DIM,) or self.obs_std.shape != (DOCKING_OBS_DIM,):
            raise ValueError(
                f"obs_mean and obs_std must be ({DOCKING_OBS_DIM},), got {self.obs_mean.shape} and {self.obs_std.shape}"
            )
        if np.any(self.obs_std <= 0):
            raise ValueError("obs_std must be > 0")
        self.weights, self.biases, self.activation, self.law = weights, biases, activation, law
        self.metadata: dict = {}
        # The layers padded into one (L, widest, widest) block: one array argument for numba.
        widest = max(max(w.shape) for w in weights)
        self._weights = np.zeros((len(weights), widest, widest))
        self._biases = np.zeros((len(weights), widest))
        self._shapes = np.array([w.shape for w in weights], dtype=np.int64)
        for i, (w, b) in enumerate(zip(weights, biases, strict=True)):
            self._weights[i, : w.shape[0], : w.shape[1]] = w
            self._biases[i, : len(b)] = b
        empty3 = np.zeros((1, 3, 1))
        law_arguments = (
            (0, 0.0, -1, empty3, np.zeros((1, 3, 6)), np.zeros(0), np.zeros(0), 1.0)
            if law is None
            else (
                2 if len(law.route_along) else 1,
                float(law.scale),
                int(law.correction_above),
                law.target_gain,
                law.state_gain,
                law.route_along,
                law.route_across,
                float(law.u_max),
            )
        )
        # _act's arguments after the observation, in its order; the scratch rows hold the layers' values
        self._arguments = (
            self.obs_mean,
            self.obs_std,
            self._weights,
            self._biases,
            self._shapes,
            ACTIVATIONS.index(activation),
            *law_arguments,
            np.zeros((2, widest)),
        )

    def __call__(self, obs) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float64)
        if obs.shape == (DOCKING_OBS_DIM,):  # one chaser: the flight's call, kept short
            out = np.empty(3)
            if not _act(obs, *self._arguments, out):
                raise ValueError("obs must be finite, got NaN/inf entries")
            return out
        if obs.ndim != 2 or obs.shape[1] != DOCKING_OBS_DIM:
            raise ValueError(
                f"obs must be ({DOCKING_OBS_DIM},) or (N, {DOCKING_OBS_DIM}), got shape {obs.shape}"
            )
        out = np.empty((len(obs), 3))
        for row, action in zip(obs, out, strict=True):
            if not _act(row, *self._arguments, action):
                raise ValueError("obs must be finite, got NaN/inf entries")
        return out

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The families' policy interface (``Policy.act``): (N, 10) -> (N, 3)."""
        return self(np.asarray(obs, dtype=np.float64).reshape(-1, DOCKING_OBS_DIM))

    def save(self, path: str | os.PathLike, metadata: dict | None = None) -> Path:
        """Write the policy to ``path`` (.npz, no pickles), with ``metadata`` as JSON."""
        path = Path(path)
        arrays = {f"weights_{i}": w for i, w in enumerate(self.weights)}
        arrays.update({f"biases_{i}": b for i, b in enumerate(self.biases)})
        header = {"format": FORMAT, "layers": len(self.weights), "activation": self.activation}
        if self.law is not None:
            header.update(
                scale=self.law.scale, u_max=self.law.u_max, correction_above=int(self.law.correction_above)
            )
            arrays.update(
                target_gain=self.law.target_gain,
                state_gain=self.law.state_gain,
                route_along=self.law.route_along,
                route_across=self.law.route_across,
            )
        header["metadata"] = metadata or {}
        with path.open("wb") as handle:
            np.savez(
                handle,
                obs_mean=self.obs_mean,
                obs_std=self.obs_std,
                header=np.array(json.dumps(header)),
                **arrays,
            )
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> CompiledPolicy:
        """A policy written by :meth:`save`; its metadata in ``.metadata``."""
        with np.load(Path(path), allow_pickle=False) as data:
            try:
                header = json.loads(str(data["header"]))
            except KeyError:
                raise ValueError(f"{path} is not a compiled policy: it has no header") from None
            if header.get("format") != FORMAT:
                raise ValueError(f"{path} is not a {FORMAT} file (its format: {header.get('format')!r})")
            law = None
            if "scale" in header:
                law = ResidualLaw(
                    header["scale"],
                    data["target_gain"],
                    data["state_gain"],
                    header["u_max"],
                    data["route_along"],
                    data["route_across"],
                    header["correction_above"],
                )
            layers = range(header["layers"])
            policy = cls(
                [data[f"weights_{i}"] for i in layers],
                [data[f"biases_{i}"] for i in layers],
                header["activation"],
                data["obs_mean"],
                data["obs_std"],
                law,
            )
        policy.metadata = header["metadata"]
        return policy


def compile_checked(
    policy,
    path: str | os.PathLike,
    metadata: dict,
    law: ResidualLaw | None = None,
    *,
    rows=1024,
    tolerance=1e-4,
) -> dict:
    """A family's trained torch ``policy`` as a :class:`CompiledPolicy` at ``path`` (with ``metadata``),
    kept only if its actions are within ``tolerance`` of ``policy.act`` on ``rows`` observations
    around the training statistics, as :func:`cwh_envs.onnx_policy.export_checked` holds an ONNX file;
    otherwise ValueError and nothing written. Returns the summary the families' export.py print.

    ``policy.net`` is a sequence of linear layers with one activation between them (dropout is off in
    flight); ``law`` the one its residual form corrects (None: the net is the policy)."""
    from cwh_envs.onnx_policy import action_difference

    linear, activations = [], set()
    for module in policy.net:
        kind = type(module).__name__
        if kind == "Linear":
            linear.append(module)
        elif kind in _TORCH_ACTIVATIONS and getattr(module, "approximate", "none") == "none":
            activations.add(_TORCH_ACTIVATIONS[kind])
        elif kind != "Dropout":
            raise ValueError(f"the policy's net holds a {module!r}, which CompiledPolicy does not compute")
    if len(activations) > 1:
        raise ValueError(f"the policy's net mixes activations {sorted(activations)}; CompiledPolicy has one")
    compiled = CompiledPolicy(
        [layer.weight.detach().double().cpu().numpy() for layer in linear],
        [layer.bias.detach().double().cpu().numpy() for layer in linear],
        activations.pop() if activations else "tanh",  # one layer alone has no activation to apply
        policy.obs_mean.double().cpu().numpy(),
        policy.obs_std.double().cpu().numpy(),
        law,
    )
    gap = action_difference(
        policy.act, compiled, policy.obs_mean.cpu().numpy(), policy.obs_std.cpu().numpy(), rows
    )
    if not gap <= tolerance:
        raise ValueError(
            f"the compiled policy's actions differ from the torch policy's by {gap:.3g} (> {tolerance:g}); "
            "nothing written"
        )
    compiled.save(path, metadata)
    return {"compiled": str(path), "task": metadata.get("task"), "max_action_difference": gap}


# reassociation lets the layers' sums vectorise (4 float64 lanes): about 2x on the MLP
@njit(cache=True, fastmath={"reassoc", "contract"})
def _act(
    obs,
    mean,
    std,
    weights,
    biases,
    shapes,
    activation,
    form,
    scale,
    correction_above,
    target_gain,
    state_gain,
    along,
    across,
    u_max,
    scratch,
    out,
):
    """One observation's action into ``out`` (3,); ``form`` 0: the MLP alone, 1: the goal law, 2: the
    route. False, and ``out`` untouched, if the observation is not finite."""
    for j in range(obs.shape[0]):
        if not math.isfinite(obs[j]):
            return False
    current, following = scratch[0], scratch[1]
    for j in range(obs.shape[0]):
        current[j] = (obs[j] - mean[j]) / std[j]
    layers = shapes.shape[0]
    for layer in range(layers):
        rows, columns = shapes[layer, 0], shapes[layer, 1]
        for i in range(rows):
            total = biases[layer, i]
            for j in range(columns):
                total += weights[layer, i, j] * current[j]
            if layer < layers - 1:
                if activation == 0:
                    total = math.tanh(total)
                elif activation == 1:
                    total = max(total, 0.0)
                else:
                    total = 0.5 * total * (1.0 + math.erf(total / math.sqrt(2.0)))
            following[i] = total
        current, following = following, current
    if form == 0:
        for i in range(3):
            out[i] = min(max(current[i], -1.0), 1.0)
        return True
    horizon = target_gain.shape[0] - 1
    steps = int(np.rint(obs[9] * horizon))
    gate = 1.0 if correction_above < 0 or steps > correction_above else 0.0  # -1: never off
    m = min(max(steps, 1), horizon)
    law = _law(obs, m, form, target_gain, state_gain, along, across)
    for i in range(3):
        action = law[i] / u_max + scale * math.tanh(current[i]) * gate
        out[i] = min(max(action, -1.0), 1.0)
    return True


@njit(cache=True)
def _law(obs, m, form, target_gain, state_gain, along, across):
    """``K_m t - L_m [r, v]`` (3,) N: t the goal (form 1) or the route's waypoints, goal and zero velocity."""
    targets = np.zeros(target_gain.shape[2])
    goal = obs[6:9]
    if form == 1:
        targets[:3] = goal
    else:
        length = math.sqrt(goal[0] ** 2 + goal[1] ** 2 + goal[2] ** 2)
        axis = goal / length
        offset = obs[:3] - goal
        along_axis = offset[0] * axis[0] + offset[1] * axis[1] + offset[2] * axis[2]
        side = offset - along_axis * axis
        norm = math.sqrt(side[0] ** 2 + side[1] ** 2 + side[2] ** 2)
        if norm <= AXIS_TOLERANCE:
            # axis x e_i for the axis's smallest component i (WaypointFeedback's fallback)
            unit = np.zeros(3)
            unit[np.argmin(np.abs(axis))] = 1.0
            side = np.array(
                [
                    axis[1] * unit[2] - axis[2] * unit[1],
                    axis[2] * unit[0] - axis[0] * unit[2],
                    axis[0] * unit[1] - axis[1] * unit[0],
                ]
            )
            norm = math.sqrt(side[0] ** 2 + side[1] ** 2 + side[2] ** 2)
        side = side / norm
        for w in range(along.shape[0]):
            targets[3 * w : 3 * w + 3] = goal + along[w] * axis + across[w] * side
        waypoints = 3 * along.shape[0]
        targets[waypoints : waypoints + 3] = goal
    law = np.zeros(3)
    for i in range(3):
        total = 0.0
        for j in range(targets.shape[0]):
            total += target_gain[m, i, j] * targets[j]
        for j in range(6):
            total -= state_gain[m, i, j] * obs[j]
        law[i] = total
    return law
