"""cwh_envs: Clohessy-Wiltshire-Hill rendezvous and keep-out docking as Gymnasium environments.

Importing the package registers ``CWHRendezvous-v0`` and ``CWHDockKOZ-v0``. Gymnasium 1.x loads
no plugin entry points, so without the import use the module-prefixed id,
``gym.make("cwh_envs:CWHRendezvous-v0")``, which imports the package first.
"""

from gymnasium.envs.registration import register, registry

from cwh_envs.dynamics import cwh_matrices
from cwh_envs.wrappers import CBFSafetyFilter

__all__ = ["CBFSafetyFilter", "cwh_matrices"]
__version__ = "0.1.0"

_ENVS = {
    "CWHRendezvous-v0": (
        "cwh_envs.rendezvous:CWHRendezvousEnv",
        "cwh_envs.vector:CWHRendezvousVectorEnv",
        80,
    ),
    "CWHDockKOZ-v0": ("cwh_envs.docking:CWHDockKOZEnv", "cwh_envs.vector:CWHDockKOZVectorEnv", 240),
}

for _env_id, (_entry, _vector_entry, _horizon) in _ENVS.items():
    if _env_id not in registry:
        # The horizon is part of the task (time-to-go is observed), so the env ends its own
        # episodes; no TimeLimit wrapper is added on top.
        register(id=_env_id, entry_point=_entry, vector_entry_point=_vector_entry)
