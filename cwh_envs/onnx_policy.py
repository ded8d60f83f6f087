"""A trained policy as an ONNX file, and that file flown as a policy (the families' export.py and
examples/fly_onnx.py).

:func:`export_policy` writes ``action = clip(net((obs - mean) / std), -1, 1)`` as one graph: input
``obs`` float32 (N, d), the observation as the env shows it; output ``action`` float32 (N, 3), the
action as the env takes it (thrust / u_max per axis), exactly what the families' ``Policy.act``
computes. Facts the flight needs (task, problem constants, whether the CBF filter is on and its
margin) go in the model's ``metadata_props`` as strings, JSON where structured; the CBF filter
itself stays :func:`cwh_envs.cbf.safe_actions`, applied outside the graph by
:func:`cwh_envs.rollout.fly`. :class:`OnnxPolicy` runs a file with onnxruntime and reads them back.

The graph is traced by torch's TorchScript-based exporter (``dynamo=False``): a static MLP needs
nothing more, and it runs with the installed torch and ``onnx`` alone, whereas the torch.export-based
exporter (torch's default since 2.9) also needs ``onnxscript``. torch, onnx and onnxruntime are
imported inside the functions: ``import cwh_envs`` needs none of them (``pip install
cwh-autoresearch[onnx]``).
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import io
import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

OPSET = 17  # onnxruntime >= 1.14 runs it; nothing in an MLP needs a newer one
INPUT, OUTPUT = "obs", "action"


def export_policy(
    net,
    obs_mean,
    obs_std,
    path: str | os.PathLike,
    metadata: dict[str, Any],
    *,
    opset: int = OPSET,
) -> Path:
    """Write ``clip(net((obs - obs_mean) / obs_std), -1, 1)`` to ``path`` as ONNX with ``metadata``.

    ``net`` is a torch module from standardised observations to unclipped actions (a family's
    ``Policy``, put in eval mode here); values of ``metadata`` that are not strings are stored as
    JSON. The file is checked with ``onnx.checker`` before it is returned.
    """
    onnx, torch = _optional("onnx", "onnx"), _optional("torch", "families")

    class Deployed(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = net
            self.register_buffer("obs_mean", torch.as_tensor(obs_mean, dtype=torch.float32).reshape(-1))
            self.register_buffer("obs_std", torch.as_tensor(obs_std, dtype=torch.float32).reshape(-1))

        def forward(self, obs):
            return torch.clamp(self.net((obs - self.obs_mean) / self.obs_std), -1.0, 1.0)

    deployed = Deployed().eval()
    example = torch.zeros(2, deployed.obs_mean.numel())
    legacy = {"dynamo": False} if "dynamo" in inspect.signature(torch.onnx.export).parameters else {}
    buffer = io.BytesIO()
    with warnings.catch_warnings(), torch.no_grad():
        # torch >= 2.9 flags the TorchScript exporter as deprecated; it is the one that needs no onnxscript.
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            deployed,
            (example,),
            buffer,
            input_names=[INPUT],
            output_names=[OUTPUT],
            dynamic_axes={INPUT: {0: "batch"}, OUTPUT: {0: "batch"}},
            opset_version=opset,
            do_constant_folding=True,
            **legacy,
        )
    model = onnx.load_from_string(buffer.getvalue())
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value if isinstance(value, str) else json.dumps(value, allow_nan=False)
    model.producer_name = "cwh_envs.onnx_policy"
    onnx.checker.check_model(model, full_check=True)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, path)
    return path


class OnnxPolicy:
    """An exported policy run by onnxruntime: observations (N, d) -> env actions (N, 3) float64.

    ``metadata`` holds the file's metadata_props with JSON values decoded (plain strings stay).
    One intra-op thread by default: the batches are small and the families' machines busy.
    """

    def __init__(self, path: str | os.PathLike, threads: int = 1) -> None:
        onnxruntime = _optional("onnxruntime", "onnx")

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.path = Path(path)
        self.session = onnxruntime.InferenceSession(
            str(self.path), options, providers=["CPUExecutionProvider"]
        )
        self.metadata = {
            key: _decode(value) for key, value in self.session.get_modelmeta().custom_metadata_map.items()
        }
        inputs = self.session.get_inputs()
        if [i.name for i in inputs] != [INPUT] or [o.name for o in self.session.get_outputs()] != [OUTPUT]:
            raise ValueError(
                f"{self.path} is not an exported policy: it needs one input {INPUT!r} and one output {OUTPUT!r}"
            )
        self.obs_dim = inputs[0].shape[1]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        return self.session.run([OUTPUT], {INPUT: obs})[0].astype(np.float64)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The families' policy interface (``Policy.act``)."""
        return self(obs)


def action_difference(act, exported: OnnxPolicy, obs_mean, obs_std, rows: int = 1024, seed: int = 0) -> float:
    """The largest |action difference| between ``act`` (e.g. a family's ``Policy.act``) and the
    exported file, on ``rows`` observations drawn around the training statistics (mean +- 2 std)."""
    mean = np.asarray(obs_mean, dtype=np.float64).reshape(-1)
    std = np.asarray(obs_std, dtype=np.float64).reshape(-1)
    obs = (mean + 2.0 * std * np.random.default_rng(seed).standard_normal((rows, len(mean)))).astype(
        np.float32
    )
    return float(np.abs(exported(obs) - np.asarray(act(obs), dtype=np.float64)).max())


def export_checked(
    policy,
    path: str | os.PathLike,
    metadata: dict[str, Any],
    source: str | os.PathLike,
    *,
    rows: int = 1024,
    tolerance: float = 1e-4,
) -> dict[str, Any]:
    """Export a family's trained ``policy`` (a ``Policy`` with ``obs_mean``, ``obs_std`` and ``act``)
    with :func:`export_policy`, then hold the file to the torch policy on ``rows`` observations.

    The metadata gains the sha256 of ``source`` (the policy.pt it came from) and the torch version.
    A file whose actions differ by more than ``tolerance`` is deleted and ValueError raised. Returns
    the one-line summary the families' export.py print (``EXPORTED: {...}``).
    """
    torch = _optional("torch", "families")
    metadata = {
        **metadata,
        "policy_sha256": hashlib.sha256(Path(source).read_bytes()).hexdigest(),
        "torch": torch.__version__,
    }
    export_policy(policy, policy.obs_mean, policy.obs_std, path, metadata)
    gap = action_difference(policy.act, OnnxPolicy(path), policy.obs_mean, policy.obs_std, rows)
    if not gap <= tolerance:
        Path(path).unlink()
        raise ValueError(f"the ONNX policy differs from the torch policy by {gap:.3g} (> {tolerance})")
    return {
        "onnx": str(path),
        "task": metadata.get("task"),
        "runtime_cbf_filter": metadata.get("runtime_cbf_filter"),
        "max_action_difference": gap,
    }


def _optional(module: str, extra: str):
    """``module``, or an ImportError naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        raise ModuleNotFoundError(
            f"cwh_envs.onnx_policy needs {module}, which is not installed: pip install 'cwh-autoresearch[{extra}]'",
            name=err.name,
        ) from err


def _decode(value: str) -> Any:
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value
