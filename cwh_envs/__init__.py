"""cwh_envs: Clohessy-Wiltshire-Hill rendezvous and keep-out docking as Gymnasium environments.

Importing the package registers ``CWHRendezvous-v0``, ``CWHDockKOZ-v1`` and ``CWHDockKOZ-v0``.
``CWHDockKOZ-v1`` scores an approach cone with a capture envelope at the port (``capture_radius``,
0.1 m by default: :mod:`cwh_envs.constraints`); ``CWHDockKOZ-v0`` keeps its original definition,
the cone's apex on the port (``capture_radius=0``). Without an approach cone the two are one env. Gymnasium 1.x loads
no plugin entry points, so without the import use the module-prefixed id,
``gym.make("cwh_envs:CWHRendezvous-v0")``, which imports the package first.
"""

from importlib.metadata import PackageNotFoundError, version

from gymnasium.envs.registration import register, registry

from cwh_envs.dynamics import cwh_matrices

__all__ = ["CBFSafetyFilter", "cwh_matrices"]
try:
    __version__ = version("cwh-autoresearch")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"


def __getattr__(name: str):
    # The filter needs the envs, the experts and proxsuite: imported when first used, so that
    # ``import cwh_envs`` (which registers the ids) costs little more than gymnasium itself.
    if name == "CBFSafetyFilter":
        from cwh_envs.wrappers import CBFSafetyFilter

        return CBFSafetyFilter
    raise AttributeError(f"module 'cwh_envs' has no attribute {name!r}")


_DOCKING = ("cwh_envs.docking:CWHDockKOZEnv", "cwh_envs.vector:CWHDockKOZVectorEnv")
_ENVS = {
    "CWHRendezvous-v0": (
        "cwh_envs.rendezvous:CWHRendezvousEnv",
        "cwh_envs.vector:CWHRendezvousVectorEnv",
        {},
    ),
    "CWHDockKOZ-v0": (*_DOCKING, {"capture_radius": 0.0}),  # as first released: Gymnasium keeps old ids
    "CWHDockKOZ-v1": (*_DOCKING, {}),
}

for _env_id, (_entry, _vector_entry, _kwargs) in _ENVS.items():
    if _env_id not in registry:
        # No max_episode_steps: the horizon is part of the task (time-to-go is observed), so the
        # env ends its own episodes with terminated=True at H; and H is a constructor argument
        # (gym.make(id, horizon=...)), which a registered TimeLimit would silently cut short.
        register(id=_env_id, entry_point=_entry, vector_entry_point=_vector_entry, kwargs=_kwargs)
