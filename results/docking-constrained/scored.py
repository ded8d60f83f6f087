"""A hand-written law on constrained docking, scored by the family's own metric: the shared part of
pd_law.py and waypoint_law.py (run as scripts, they import it from beside them)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from cwh_envs.rollout import fly

FAMILY = Path(__file__).resolve().parents[2] / "families" / "docking-constrained"


def load_train():
    spec = importlib.util.spec_from_file_location("constrained_train", FAMILY / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def scored(train, law, held_out, cbf: bool) -> dict:
    """``law`` flown from ``held_out``'s starts (through the multi-constraint filter when ``cbf``),
    the family's docking_metrics against the split's own expert; with the filter, also the family's
    Monte Carlo auxiliary under its dispersions (``dispersed``), as a run records it."""
    problem = train.PROBLEM
    margin = problem.margin if cbf else None
    flight = fly(problem, law, held_out.starts, held_out.goals, cbf_margin=margin)
    metrics = train.docking_metrics(flight, held_out.trajectory_thrust())
    if cbf:
        dispersed = fly(
            problem,
            law,
            held_out.starts,
            held_out.goals,
            cbf_margin=margin,
            dispersions=train.DISPERSIONS,
            dispersion_seed=train.DISPERSION_SEED,
        )
        metrics["dispersed"] = train.dispersed_metrics(dispersed)
    return metrics
