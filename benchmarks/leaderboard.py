"""The leaderboard: every controller and every family's promoted policy, flown on the sealed test split.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/leaderboard.py                 # all three tasks
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/leaderboard.py --tasks docking --retime
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/leaderboard.py --starts 16 --out /tmp/lb   # a quick look

For each task (rendezvous, docking, constrained docking) and on the same starts (the family's sealed
test split, 1024 screened starts), it flies:

- the open-loop expert (the split's own demonstrations), receding-horizon MPC
  (:class:`cwh_envs.mpc.RecedingHorizon`), the closed-form shrinking-horizon minimum-energy law
  (:class:`cwh_envs.controllers.MinEnergyFeedback`; through the task's CBF filter on docking), on
  constrained docking the same law re-planned through a hand-drawn route of waypoints
  (:class:`cwh_envs.controllers.WaypointFeedback`, through the filter) and the PD law (through the
  filter on docking); on docking the robust rows (issue 58): the tube MPC alone and on the navigation
  filter, the law and the tube MPC through the robust CBF with its navigation margins sized by the
  declared bounds or by the navigation filter's own covariance (``covariance-sized``): nothing learned;
- behaviour cloning at the family's promoted best (``family.json``) and at the best recipe a
  key-free agent campaign certified (:data:`AGENT_RECIPES`), each trained by the family's own
  train.py at every seed of ``--seeds`` (the family best under the training time budget it was
  certified under, when its entry names one: ``AUTORESEARCH_TIME_BUDGET``, as the loop grants it),
  and on constrained docking the robust hand recipe (:data:`ROBUST_RECIPES`: an audit's promoted
  recipe at its campaign's budget), each flown through the filters its config names;
- SB3 PPO and SAC (examples/sb3_compare.py's hyperparameters and budgets) at the same seeds;
- the long RL runs (issue 60) whose summary is committed under results/rl-baselines/<task>/: each
  flown at its own seeds from the checkpoints benchmarks/rl_baselines.py left under runs/rl-baselines
  (refused unless they are the ones the summary scored), with its env steps and rliable's IQM.

Each row is scored by the family's own metric code (its train.py's ``rendezvous_metrics`` /
``docking_metrics``) and adds the tail (99th percentile and largest terminal distance over the
starts), the violation rate of every constraint, Δv and energy over the open-loop expert's from the
same starts, the compute per step (one start at a time, on this CPU: p50 and p99 in µs, filter
included; timed in a pass of its own, ``--retime`` alone repeats it), and the success rate under the
families' fixed dispersion set (the docking families' ``DISPERSIONS``; rendezvous has none of its
own and flies under the same set). Learned rows give the mean over seeds beside the spread; their
tail columns pool the starts of every seed (the worst start of any seed is the max).

Trained policies, SB3 models and per-row measurements are cached under ``--work`` (runs/leaderboard,
never committed), so a re-run only measures what is missing. Writes ``leaderboard.json``,
``leaderboard.md`` and ``leaderboard_<task>.png`` to ``--out`` (results/). MPC on constrained
docking re-solves a second-order-cone program at each of 240 steps (38 ms a step, about 9 s a
start, here): it flies the first ``MPC_STARTS`` starts of the split (32: 24 min on one core, nominal
and dispersed, partly beside another job), which its row says.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import importlib.util
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from autoresearch.audit.outcome import promoted
from autoresearch.campaign import Campaign
from autoresearch.editable import patch
from autoresearch.execution.runner import TIME_BUDGET_ENV
from cwh_envs.controllers import MinEnergyFeedback, WaypointFeedback, pd_action
from cwh_envs.core import filter_actions
from cwh_envs.datasets import evaluation_set
from cwh_envs.mpc import RecedingHorizon
from cwh_envs.navigation import NavigationFilter
from cwh_envs.prepare import load_train
from cwh_envs.robust_cbf import ErrorBounds
from cwh_envs.rollout import fly
from cwh_envs.tube_mpc import TubeMPC

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("rendezvous", "docking", "docking-constrained")
SB3_PROBLEM = {
    "rendezvous": "rendezvous",
    "docking": "docking+cbf",
    "docking-constrained": "docking-constrained+cbf",
}
# The long RL rows (issue 60), each flown when results/rl-baselines/<task>/<label>.json is committed
# (label: the algo, or algo-tag for a recipe beyond the zoo's settings).
RL_ROWS = {
    "ppo": "PPO (long run)",
    "ppo-term25": "PPO, terminal weight 25 (long run)",
    "ppo-term25-lin": "PPO, terminal weight 25, learning rate annealed (long run)",
    "residual-ppo": "residual PPO (long run)",
    "residual-ppo-std4-term10": "residual PPO, log std -4, terminal weight 10 (long run)",
    "bc-ppo": "cloning-initialised PPO (long run)",
    "sac": "SAC (long run)",
}
# Long RL rows also flown through the covariance-sized robust filter with its stop line, on the
# navigation filter (issue 58's deployment layers): the same checkpoints as the row above them, which
# trained through the nominal filter. Run-time assurance is a layer apart from the policy, so the
# learned correction is flown under the one the routed law survives the Monte Carlo with.
RL_ROBUST_ROWS = {"docking-constrained": ("residual-ppo-std4-term10",)}
RL_ROBUST_SUFFIX = " + covariance-sized robust CBF with stop line + navigation filter"
RL_WORK = ROOT / "runs" / "rl-baselines"  # where benchmarks/rl_baselines.py keeps each seed's checkpoint
MPC_STARTS = {"docking-constrained": 32}  # the rest fly every start of the split
TIMED_STARTS = 8  # starts flown one at a time for the compute column (MPC on constrained docking: 2)
# Dispersed flights of every row (issue 58): the families' DISPERSIONS (1 sigma) and the same scaled
# by 3, the stress set the constrained family reports beside its auxiliary.
DISPERSION_LEVELS = {"1sigma": 1.0, "3sigma": 3.0}
ROBUST_K_SIGMA = 3.0  # the robust filter's rows: sized for the 1-sigma set at 3 sigma, as the family's lever
SUBSET = 16  # deterministic rows also keep their metric on the first SUBSET starts (tests re-measure it)
# The best recipe a key-free agent campaign certified on each task (the audit's promoted config), as
# committed; the family's own promoted best is read from its family.json.
AGENT_RECIPES = {
    "rendezvous": (
        "results/evidence/rendezvous-gp (GP, 77 experiments; candidate a390c2fb)",
        {
            "N_DEMOS": 573,
            "EPOCHS": 96,
            "LEARNING_RATE": 0.0002621822213911771,
            "BATCH_SIZE": 168,
            "WEIGHT_DECAY": 0.0021755787660961185,
            "GRAD_CLIP": 4.693079115265057,
            "HIDDEN_DIM": 329,
            "N_LAYERS": 3,
            "ACTIVATION": "tanh",
            "DROPOUT": 0.0,
        },
    ),
    "docking": (
        "results/evidence/docking-gp (GP, graded constraints; pruned to 4 edits, 3b7094da)",
        {"N_DEMOS": 256, "N_LAYERS": 4, "ACTIVATION": "gelu", "RECOVERY_AUGMENT_FRAC": 0.5},
    ),
    "docking-constrained": (
        "results/docking-constrained/gp (GP, 16 runs; it0012, not strict-feasible)",
        {
            "N_DEMOS": 256,
            "EPOCHS": 120,
            "LEARNING_RATE": 0.0049999999999999975,
            "BATCH_SIZE": 256,
            "WEIGHT_DECAY": 0.0006023133462519599,
            "GRAD_CLIP": 0.9658987235279884,
            "HIDDEN_DIM": 128,
            "N_LAYERS": 4,
            "ACTIVATION": "gelu",
            "DROPOUT": 0.0573051372325354,
            "RUNTIME_CBF_FILTER": True,
            "RECOVERY_AUGMENT_FRAC": 0.5,
        },
    ),
}


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=[1, 2, 3], help="training seeds of learned rows"
    )
    parser.add_argument(
        "--starts",
        type=int,
        default=None,
        help="fly only the first N test starts (the split is nested in N: only those are built)",
    )
    parser.add_argument(
        "--rows", nargs="+", default=None, help="only these controllers (names as in the table)"
    )
    parser.add_argument(
        "--mpc-starts",
        type=int,
        default=MPC_STARTS["docking-constrained"],
        help="starts MPC flies on constrained docking (a SOCP per step: seconds a start)",
    )
    parser.add_argument("--retime", action="store_true", help="measure the compute column again (run alone)")
    parser.add_argument(
        "--fresh", action="store_true", help="ignore cached measurements (not trained policies)"
    )
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "leaderboard")
    parser.add_argument("--out", type=Path, default=ROOT / "results")
    return parser.parse_args(argv)


# ------------------------------------------------------------------------------------ the rows


@dataclass
class Task:
    """One task's family code and sealed test split (the first ``n`` starts)."""

    name: str
    train: Any  # the family's train.py as a module
    held_out: Any  # cwh_envs.datasets.Demonstrations
    dispersions: dict

    @classmethod
    def load(cls, name: str, n: int | None) -> Task:
        train = load_train(ROOT / "families" / name)
        # splits are nested in n: the first n starts of the test split, and only those are built
        held_out = evaluation_set(train.TASK, n or train.N_TEST, problem=train.PROBLEM, split="test")
        dispersions = (
            getattr(train, "DISPERSIONS", None) or load_train(ROOT / "families" / "docking").DISPERSIONS
        )
        return cls(name, train, held_out, dispersions)

    @property
    def problem(self):
        return self.train.PROBLEM

    @property
    def docking(self) -> bool:
        return self.train.TASK == "docking"

    def defaults(self) -> dict:
        """The family's editable block as it stands."""
        return family_defaults(self.train)

    def metrics(self, flight) -> dict:
        expert = self.held_out.trajectory_thrust()[: len(flight.terminal_distance)]
        if self.docking:
            return self.train.docking_metrics(flight, expert)
        return self.train.rendezvous_metrics(flight, expert)

    @property
    def bounds(self) -> ErrorBounds:
        """The robust filter's error bounds: the 1-sigma dispersions at ROBUST_K_SIGMA."""
        return self.bounds_at(ROBUST_K_SIGMA)

    def bounds_at(self, k_sigma: float) -> ErrorBounds:
        """The 1-sigma dispersions at ``k_sigma``: a learned row's robust filter as its recipe sizes it."""
        return ErrorBounds.from_dispersions(self.dispersions, k_sigma=k_sigma)

    def fly(
        self,
        policy,
        cbf: bool,
        starts: int | None = None,
        scale: float | None = None,
        robust: bool = False,
        navigation: bool = False,
        cbf_navigation: str = "bounds",
        stop_line: bool = False,
        k_sigma: float = ROBUST_K_SIGMA,
    ):
        """Nominal, or under the dispersions scaled by ``scale`` (the filter on the estimate; with
        ``navigation``, everything on the navigation filter's estimate, sized by :attr:`bounds`;
        ``cbf_navigation`` and ``stop_line`` as :func:`cwh_envs.rollout.fly`'s ``cbf_`` ones; the robust
        filter sized at ``k_sigma``)."""
        held = self.held_out if starts is None else self.held_out.take(starts)
        return fly(
            self.problem,
            policy,
            held.starts,
            held.goals if self.docking else None,
            cbf_margin=self.problem.margin if cbf else None,
            cbf_bounds=self.bounds_at(k_sigma) if robust else None,
            dispersions=None if scale is None else {k: scale * v for k, v in self.dispersions.items()},
            dispersion_seed=getattr(self.train, "DISPERSION_SEED", 0),
            navigation=self.bounds if navigation else None,
            cbf_navigation=cbf_navigation,
            cbf_stop_line=stop_line,
        )

    def fly_row(self, entry: Entry, policy, starts: int | None = None, scale: float | None = None):
        """:meth:`fly` through the filters a row names (cbf, robust, navigation, cbf_navigation, stop_line)."""
        return self.fly(
            policy,
            entry.cbf,
            starts,
            scale,
            entry.robust,
            entry.navigation,
            entry.cbf_navigation,
            entry.stop_line,
            entry.k_sigma,
        )


def family_defaults(train: Any) -> dict:
    """A family's editable block as it stands (its train.py as a module)."""
    return {name: getattr(train, name) for name in train.CONFIG_NAMES}


@dataclass
class Entry:
    """A leaderboard row to measure: ``make(seed)`` returns a policy on observations."""

    name: str
    # "classical", "bc", "sb3", "rl" (a long run of benchmarks/rl_baselines.py) or "rl-family" (the RL
    # family's train.py, as the loop runs it)
    kind: str
    cbf: bool
    make: Any
    source: str
    config: dict = field(default_factory=dict)
    time_budget: float | None = None  # training seconds train.py is granted (the recipe's, when certified so)
    starts: int | None = None  # fewer starts than the split (MPC on constrained docking)
    robust: bool = False  # through the robust filter (cwh_envs.robust_cbf), sized by Task.bounds
    sized: bool = False  # a controller sized by Task.bounds itself (the tube MPC), no filter
    navigation: bool = False  # flown on a navigation filter sized by Task.bounds (rollout.fly's navigation)
    # what sizes the robust filter's navigation margins: "bounds" (Task.bounds) or "covariance" (the
    # navigation filter's own, rollout.fly's cbf_navigation)
    cbf_navigation: str = "bounds"
    stop_line: bool = False  # the robust filter's stop line (rollout.fly's cbf_stop_line)
    # the robust filter's size (a learned row's: its recipe's ROBUST_FILTER_K)
    k_sigma: float = ROBUST_K_SIGMA
    rl: dict | None = None  # an RL row's committed summary (benchmarks/rl_baselines.py): its seeds and budget


class OpenLoop:
    """Replays the split's expert thrust: row i of the batch is start i, the step read from tau."""

    def __init__(self, thrust: np.ndarray, u_max: float):
        self.actions, self.horizon = thrust / u_max, thrust.shape[1]

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        step = np.rint((1.0 - obs[:, -1].astype(np.float64)) * self.horizon).astype(int)
        return self.actions[np.arange(len(obs)), step]


def with_stop_line(entry: Entry) -> Entry:
    """A covariance-sized robust row flown again with the robust filter's stop line
    (:func:`cwh_envs.robust_cbf.robust_safe_actions`' ``stop_line``). Its name and source text say so
    in the words its committed record and row cache were keyed by."""
    return dataclasses.replace(
        entry,
        name=entry.name.replace("robust CBF +", "robust CBF with stop line +"),
        source=entry.source.replace("covariance)", "covariance; stop line)"),
        stop_line=True,
    )


def flown_filters(train: Any, config: dict) -> dict:
    """A learned row's filters as :class:`Entry` fields: what its family's own ``safety_filter`` (in
    ``train``, its train.py as a module) gives the recipe (the robust filter at the recipe's k,
    covariance-sized with the stop line where it asks), so that the row flies as train.py flies it;
    none on a family without a filter (rendezvous)."""
    safety = train.safety_filter(config) if hasattr(train, "safety_filter") else {}
    bounds = safety.get("cbf_bounds")
    return {
        "cbf": "cbf_margin" in safety,
        "robust": bounds is not None,
        "navigation": "navigation" in safety,
        "cbf_navigation": safety.get("cbf_navigation", "bounds"),
        "stop_line": safety.get("cbf_stop_line", False),
        "k_sigma": bounds.k_sigma if bounds is not None else ROBUST_K_SIGMA,
    }


def entries(task: Task, work: Path, seeds: list[int], mpc_starts: int | None = None) -> list[Entry]:
    problem, docking = task.problem, task.docking
    plain = problem.replace(speed_limit=None, approach_cone=None) if docking else problem
    mpc_starts = (mpc_starts or MPC_STARTS[task.name]) if task.name in MPC_STARTS else None
    # the law the robust filter's rows fly: the routed one on constrained docking, else the closed form
    routed = task.name == "docking-constrained"
    law_name = "routed feedback" if routed else "closed-form feedback"
    law = (lambda seed: WaypointFeedback(problem)) if routed else (lambda seed: MinEnergyFeedback(plain))
    bounds_source = f"ErrorBounds of the 1-sigma DISPERSIONS, k={ROBUST_K_SIGMA:g}"
    rows = [
        Entry(
            "open-loop expert",
            "classical",
            False,
            lambda seed: OpenLoop(task.held_out.trajectory_thrust(), problem.u_max),
            "the split's own demonstrations, replayed",
        ),
        Entry(
            "MPC",
            "classical",
            False,
            lambda seed: RecedingHorizon(problem),
            "cwh_envs.mpc",
            starts=mpc_starts,
        ),
        *(
            [  # the robust MPC (issue 58): one plan per episode on constraints tightened by its tube
                Entry(
                    "tube MPC (robust)",
                    "classical",
                    False,
                    lambda seed: TubeMPC(problem, task.bounds),
                    f"cwh_envs.tube_mpc ({bounds_source})",
                    sized=True,
                ),
                Entry(  # the same on the navigation filter's estimate (cwh_envs.navigation)
                    "tube MPC + navigation filter (robust)",
                    "classical",
                    False,
                    lambda seed: TubeMPC(problem, task.bounds, navigation=True),
                    f"cwh_envs.tube_mpc + cwh_envs.navigation ({bounds_source})",
                    sized=True,
                ),
                Entry(  # the layers together: the tube MPC under the robust filter, both on the navigation filter
                    "tube MPC + robust CBF + navigation filter (robust)",
                    "classical",
                    True,
                    lambda seed: TubeMPC(problem, task.bounds),
                    f"cwh_envs.tube_mpc + cwh_envs.robust_cbf + cwh_envs.navigation ({bounds_source})",
                    robust=True,
                    sized=True,
                    navigation=True,
                ),
                tube_covariance
                := Entry(  # the robust filter's navigation margins from the navigation filter's covariance
                    "tube MPC + covariance-sized robust CBF + navigation filter (robust)",
                    "classical",
                    True,
                    lambda seed: TubeMPC(problem, task.bounds),
                    f"cwh_envs.tube_mpc + cwh_envs.robust_cbf (navigation margins from cwh_envs.navigation's "
                    f"covariance) + cwh_envs.navigation ({bounds_source})",
                    robust=True,
                    sized=True,
                    navigation=True,
                    cbf_navigation="covariance",
                ),
                with_stop_line(tube_covariance),
            ]
            if docking
            else []
        ),
        Entry(
            "closed-form feedback" + (" + CBF" if docking else ""),
            "classical",
            docking,
            lambda seed: MinEnergyFeedback(plain),
            "cwh_envs.controllers.MinEnergyFeedback",
        ),
        *(
            [  # constrained docking: the same law re-planned through a hand-drawn route (the cone's way in)
                Entry(
                    "routed feedback + CBF",
                    "classical",
                    True,
                    lambda seed: WaypointFeedback(problem),
                    "cwh_envs.controllers.WaypointFeedback (CONE_ROUTE)",
                )
            ]
            if task.name == "docking-constrained"
            else []
        ),
        *(
            [  # the law above it through the robust filter (issue 58): the price of robustness beside it
                Entry(
                    f"{law_name} + robust CBF",
                    "classical",
                    True,
                    law,
                    f"cwh_envs.robust_cbf ({bounds_source})",
                    robust=True,
                ),
                Entry(  # the same on flight software's navigation filter (cwh_envs.navigation)
                    f"{law_name} + robust CBF + navigation filter",
                    "classical",
                    True,
                    law,
                    f"cwh_envs.robust_cbf + cwh_envs.navigation ({bounds_source})",
                    robust=True,
                    navigation=True,
                ),
                law_covariance
                := Entry(  # its navigation margins sized by the navigation filter's own covariance
                    f"{law_name} + covariance-sized robust CBF + navigation filter",
                    "classical",
                    True,
                    law,
                    f"cwh_envs.robust_cbf (navigation margins from cwh_envs.navigation's covariance) + "
                    f"cwh_envs.navigation ({bounds_source})",
                    robust=True,
                    navigation=True,
                    cbf_navigation="covariance",
                ),
                with_stop_line(law_covariance),
            ]
            if docking
            else []
        ),
        Entry(
            "PD" + (" + CBF" if docking else ""),
            "classical",
            docking,
            lambda seed: lambda obs: pd_action(obs, plain),
            "cwh_envs.controllers.pd_action",
        ),
    ]
    family_json = json.loads((ROOT / "families" / task.name / "family.json").read_text(encoding="utf-8"))
    best = family_json.get("best")
    recipes = []  # (name, source, config, budget, the train.py module that trains it)
    if best:  # trained under the budget it was certified under, if any: EPOCHS may not fit in it
        recipe = (best["config"], best.get("time_budget"))
        recipes.append(("family best (BC)", f"families/{task.name}/family.json best", *recipe, task.train))
    source, config = AGENT_RECIPES[task.name]
    recipes.append((FIRST_CAMPAIGN, source, config, None, task.train))
    for name, by_task in ((ROBUST_RECIPE, ROBUST_RECIPES), (RL_FAMILY_ROW, RL_FAMILY_RECIPES)):
        if task.name in by_task:
            family, campaign = by_task[task.name]
            train = task.train if family == task.name else load_train(ROOT / "families" / family)
            source = f"{campaign} (its audit's promoted recipe)"
            recipes.append((name, source, *audited_recipe(campaign), train))
    for name, source, config, budget, train in recipes:
        filters = flown_filters(train, {**family_defaults(train), **config})
        rows.append(
            Entry(
                name,
                "bc" if train is task.train else "rl-family",
                filters.pop("cbf"),
                lambda seed, c=config, n=name, b=budget, t=train: trained_by_family(
                    task, work, n, c, seed, b, t
                ),
                source,
                config,
                budget,
                **filters,
            )
        )
    for algo in ("ppo", "sac"):
        rows.append(
            Entry(
                f"SB3 {algo.upper()}",
                "sb3",
                docking,
                lambda seed, a=algo: trained_sb3(task, work, a, seed),
                f"examples/sb3_compare.py ({SB3_PROBLEM[task.name]})",
            )
        )
    # the long RL runs (issue 60) committed for this task: their own seeds and budget, flown from the
    # checkpoints benchmarks/rl_baselines.py left under runs/rl-baselines (the filter in the loop on docking)
    for label, name in RL_ROWS.items():
        rl = rl_summary(ROOT / "results" / "rl-baselines" / task.name / f"{label}.json")
        if rl and not rl["smoke"]:  # a smoke summary is plumbing, not a row
            rows.append(
                Entry(
                    name,
                    "rl",
                    docking,
                    lambda seed, rl=rl: trained_rl(task, rl, seed),
                    f"benchmarks/rl_baselines.py ({SB3_PROBLEM[task.name]})",
                    rl=rl,
                )
            )
            if label in RL_ROBUST_ROWS.get(task.name, ()):
                rows.append(through_robust_filter(rows[-1]))
    return rows


def through_robust_filter(entry: Entry) -> Entry:
    """An RL row's checkpoints flown through the covariance-sized robust filter with its stop line
    (at ROBUST_K_SIGMA) on the navigation filter, in place of the nominal filter it trained through
    (:data:`RL_ROBUST_ROWS`)."""
    return dataclasses.replace(
        entry,
        name=entry.name + RL_ROBUST_SUFFIX,
        source=entry.source.removesuffix(")") + "; flown through cwh_envs.robust_cbf, covariance-sized, "
        "with its stop line, on cwh_envs.navigation; trained through the nominal filter)",
        robust=True,
        navigation=True,
        cbf_navigation="covariance",
        stop_line=True,
    )


# Issue 60, item 3: the RL family's recipe as its audit promoted it (PPO tuned through the family
# contract), trained by that family's train.py under its campaign's budget, flown as it flies it.
RL_FAMILY_ROW = "PPO tuned by Optuna TPE (RL family)"
RL_FAMILY_RECIPES = {"docking": ("docking-rl", "results/rl-family/docking-rl-tpe")}

FIRST_CAMPAIGN = "first GP campaign (BC)"  # AGENT_RECIPES: the first key-free campaign's certified recipe
# Issue 58's learned robust row: a recipe written by hand and audited on the sealed split (its reseeds
# passed the robust protocol's gate), not one the agent found from cold; its row says which campaign.
ROBUST_RECIPE = "robust hand recipe (BC)"
ROBUST_RECIPES = {
    "docking-constrained": ("docking-constrained", "results/agent-levers/docking-constrained-best-nav-robust")
}  # task: (the family that trains it, its campaign), as RL_FAMILY_RECIPES


def audited_recipe(campaign: str) -> tuple[dict, float | None]:
    """The recipe a campaign's audit promoted (:func:`autoresearch.audit.outcome.promoted`: the pruned
    one where leave-one-out promoted it) and the training budget its campaign granted."""
    root = ROOT / campaign
    found = promoted(json.loads((root / "audit.json").read_text(encoding="utf-8")))
    if found is None:
        raise ValueError(f"{campaign}: its audit promoted no recipe")
    budget = json.loads((root / "campaign.json").read_text(encoding="utf-8"))["settings"].get("time_budget")
    return found[1]["config"], budget


def produced_by(campaign: str) -> str:
    """What produced a learned row's recipe, in words: the campaign's proposer, protocol or space,
    runs and their budget, and whether it started from a recipe or from earlier campaigns."""
    root = ROOT / campaign
    meta = json.loads((root / "campaign.json").read_text(encoding="utf-8"))
    settings = meta["settings"]
    runs = sum(r.status.started_a_run for r in Campaign(root).records())  # the baseline included
    where = (
        f"{settings['protocol']} protocol"
        if settings.get("protocol")
        else {"random-range": "random-range space", "bounds": "bounds space"}.get(
            settings.get("space"), "whole space"
        )
    )
    budget = (
        f"{runs} runs of {settings['time_budget']:g} s" if settings.get("time_budget") else f"{runs} runs"
    )
    parts = [f"{meta['proposer'].upper()} campaign", where, budget]
    if settings.get("enqueue"):
        parts.append("a hand recipe enqueued")
    if settings.get("warm_start"):
        parts.append("warm-started")
    return ", ".join(parts) + f" ({campaign})"


def family_best_campaign(task: str) -> str | None:
    """The campaign the family's promoted best came from (its ledger's last promotion)."""
    ledger = json.loads((ROOT / "families" / task / "ledger.json").read_text(encoding="utf-8"))
    promotions = ledger.get("promotions") or []
    return (promotions[-1].get("source") or {}).get("campaign") if promotions else None


ROW_ORDER = (
    "open-loop expert",
    "MPC",
    "tube MPC (robust)",
    "tube MPC + navigation filter (robust)",
    "tube MPC + robust CBF + navigation filter (robust)",
    "tube MPC + covariance-sized robust CBF + navigation filter (robust)",
    "tube MPC + covariance-sized robust CBF with stop line + navigation filter (robust)",
    "closed-form feedback",
    "routed feedback",
    "closed-form feedback + robust CBF",
    "routed feedback + robust CBF",
    "closed-form feedback + robust CBF + navigation filter",
    "routed feedback + robust CBF + navigation filter",
    "closed-form feedback + covariance-sized robust CBF + navigation filter",
    "routed feedback + covariance-sized robust CBF + navigation filter",
    "closed-form feedback + covariance-sized robust CBF with stop line + navigation filter",
    "routed feedback + covariance-sized robust CBF with stop line + navigation filter",
    "PD",
    "family best (BC)",
    "robust hand recipe (BC)",
    "first GP campaign (BC)",
    "SB3 PPO",
    "SB3 SAC",
    *(row for name in RL_ROWS.values() for row in (name, name + RL_ROBUST_SUFFIX)),
    RL_FAMILY_ROW,
)


def rank(controller: str) -> int:
    """A row's place in its task's table (a row measured again keeps its place)."""
    return ROW_ORDER.index(controller if controller in ROW_ORDER else controller.removesuffix(" + CBF"))


def slug(name: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in name.lower()).strip("-")


def trained_by_family(
    task: Task,
    work: Path,
    name: str,
    config: dict,
    seed: int,
    time_budget: float | None = None,
    train: Any = None,
):
    """A family's train.py (``train``, as a module: the task's own by default, the RL family's for its
    row on docking) with ``config`` patched into its editable block, trained at ``seed`` and granted
    ``time_budget`` training seconds when given (as the loop grants them), once: the policy is kept under
    ``work``, beside its runs.jsonl record; loaded by the family's own ``load_policy`` as a policy on
    observations."""
    module = train or task.train
    run = work / task.name / slug(name) / (f"s{seed}" + (f"-budget{time_budget:g}" if time_budget else ""))
    with contextlib.suppress(FileNotFoundError):  # not trained yet
        policy, record = module.load_policy(run)
        if all(record["config"].get(k) == v for k, v in config.items()):
            return policy.act
    run.mkdir(parents=True, exist_ok=True)
    source = Path(module.__file__).read_text(encoding="utf-8")
    (run / "train.py").write_text(patch(source, config), encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k != TIME_BUDGET_ENV}
    if time_budget is not None:
        env[TIME_BUDGET_ENV] = f"{time_budget:g}"
    print(f"[train] {task.name}: {name} at seed {seed} ...", flush=True)
    started = time.perf_counter()
    with open(run / "stdout.txt", "w", encoding="utf-8") as log:
        subprocess.run(
            [sys.executable, "train.py", "--seed", str(seed), "--out", ".", "--runs-log", "runs.jsonl"],
            cwd=run,
            env=env,
            check=True,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    print(f"[train] {task.name}: {name} at seed {seed}: {time.perf_counter() - started:.0f} s", flush=True)
    return module.load_policy(run)[0].act


@functools.cache  # one module per script: the rows and seeds share it
def _script(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _sb3_compare():
    return _script("sb3_compare", ROOT / "examples" / "sb3_compare.py")


def _rl_baselines():
    return _script("rl_baselines", ROOT / "benchmarks" / "rl_baselines.py")


def trained_sb3(task: Task, work: Path, algo: str, seed: int):
    """SB3 ``algo`` trained as examples/sb3_compare.py trains it (its hyperparameters, budget and
    start pool) at ``seed``, once; the model and its VecNormalize statistics are kept under ``work``."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    sb3 = _sb3_compare()
    name = SB3_PROBLEM[task.name]
    out = work / task.name / f"sb3-{algo}" / f"s{seed}"
    model_path = out / "models" / f"{algo}_{name}.zip"
    if not model_path.exists():
        (out / "models").mkdir(parents=True, exist_ok=True)
        args = argparse.Namespace(
            seed=seed,
            smoke=False,
            timesteps=150_000,
            sac_timesteps=15_000,
            eval_points=4,
            out=out,
            tensorboard=None,
            vec_env="native",
            start_pool=sb3.START_POOL,
        )
        problem = {"name": name, **sb3.PROBLEMS[name]}
        print(f"[train] {task.name}: SB3 {algo} at seed {seed} ...", flush=True)
        result = sb3.train_sb3(algo, problem, task.train, sb3.EvalSet(task.train, problem["cbf"]), args)
        (out / "train.json").write_text(json.dumps(result, default=float, indent=1), encoding="utf-8")
    model = sb3.ALGOS[algo].load(model_path, device="cpu")
    venv = make_vec_env(sb3.PROBLEMS[name]["env_id"], n_envs=1)
    normalizer = VecNormalize.load(str(out / "models" / f"{algo}_{name}_vecnormalize.pkl"), venv)
    normalizer.training = False

    def act(obs: np.ndarray) -> np.ndarray:
        action, _ = model.predict(normalizer.normalize_obs(obs), deterministic=True)
        return np.clip(action.astype(np.float64), -1.0, 1.0)

    return act


def rl_summary(path: Path) -> dict | None:
    """What a leaderboard row needs of a committed rl_baselines summary: its algorithm, budget, seeds,
    command, and the env steps each seed's scored checkpoint had trained (None: not committed)."""
    if not path.exists():
        return None
    summary = json.loads(path.read_text(encoding="utf-8"))
    keys = (
        "algo",
        "env_steps",
        "seeds",
        "command",
        "smoke",
        "residual_scale",
        "tag",
        "reward",
        "log_std_init",
    )
    rl = {k: summary[k] for k in keys if k in summary}
    rl["checkpoint_steps"] = {str(r["seed"]): r["curve"][-1]["timesteps"] for r in summary["curves"]}
    return rl


def trained_rl(task: Task, rl: dict, seed: int, work: Path = RL_WORK):
    """A long RL row's policy at ``seed``: the checkpoint benchmarks/rl_baselines.py left under
    ``work``, refused unless it is the one the committed summary scored (same env steps)."""
    baselines = _rl_baselines()
    recipe = ["--residual-scale", str(rl["residual_scale"])] if "residual_scale" in rl else []
    recipe += ["--tag", rl["tag"]] if "tag" in rl else []
    recipe += ["--reward", *(f"{k}={v!r}" for k, v in rl["reward"].items())] if "reward" in rl else []
    recipe += ["--log-std-init", repr(rl["log_std_init"])] if "log_std_init" in rl else []
    recipe += ["--lr-anneal"] if rl.get("lr_anneal") else []
    args = baselines.parse_args(["--task", task.name, "--algo", rl["algo"], *recipe])
    run = baselines.Row(args)
    work = work / task.name / args.label / f"s{seed}"
    if not all((work / name).exists() for name in (baselines.MODEL, baselines.STATISTICS)):
        raise SystemExit(f"{rl['algo']} seed {seed}: no checkpoint in {work}; train it: {rl['command']}")
    model, normalizer = run.load(work, run.envs(seed, 1))
    if model.num_timesteps != rl["checkpoint_steps"][str(seed)]:
        raise SystemExit(
            f"{rl['algo']} seed {seed}: the checkpoint in {work} has trained {model.num_timesteps:,} env "
            f"steps, the committed row {rl['checkpoint_steps'][str(seed)]:,}: re-run its command "
            f"({rl['command']}) so that the two agree"
        )
    normalizer.training = False
    return run.policy(model, normalizer)


# ------------------------------------------------------------------------------- measurement


def measure(task: Task, entry: Entry, seeds: list[int]) -> dict:
    """Every column but the compute one, for one row: one flight per seed (one in all for a
    deterministic controller), nominal and under the dispersion set."""
    per_seed = []
    for seed in (entry.rl["seeds"] if entry.rl else seeds) if entry.kind != "classical" else [None]:
        policy = entry.make(seed)
        flight = task.fly_row(entry, policy, entry.starts)
        metrics = task.metrics(flight)
        result = {
            "seed": seed,
            "metrics": metrics,
            "terminal_distance": flight.terminal_distance.tolist(),
            "violation_rates": violation_rates(task, flight),
        }
        if isinstance(policy, RecedingHorizon):
            result["mpc"] = mpc_counts(policy)
        if isinstance(policy, TubeMPC):
            result["plans"] = dict(policy.counts)
        result["dispersed"] = {}
        for level, scale in DISPERSION_LEVELS.items():
            disturbed = entry.make(seed)
            dispersed = task.fly_row(entry, disturbed, entry.starts, scale)
            result["dispersed"][level] = dispersed_summary(dispersed)
            if isinstance(
                disturbed, RecedingHorizon
            ):  # a disturbed state can leave every re-solve infeasible
                result["dispersed"][level]["mpc"] = mpc_counts(disturbed)
            if isinstance(disturbed, TubeMPC):  # how each episode's plan was found from the estimate
                result["dispersed"][level]["plans"] = dict(disturbed.counts)
        result["dispersed_success_rate"] = result["dispersed"]["1sigma"]["success_rate"]
        if entry.kind == "classical":
            n = min(SUBSET, len(flight.terminal_distance))
            # A row that flies no more than SUBSET starts (MPC on constrained docking) is its own subset.
            first = flight if n == len(flight.terminal_distance) else task.fly_row(entry, entry.make(seed), n)
            result["subset"] = {"n_starts": n, "metric": task.metrics(first)[task.train.METRIC]}
        per_seed.append(result)
    return {"per_seed": per_seed}


def mpc_counts(policy: RecedingHorizon) -> dict:
    return {
        "solves": int(policy.solves.sum()),
        "infeasible_resolves": int(policy.infeasible.sum()),
        "fallbacks": int(policy.fallbacks.sum()),
        "soft_replans": int(policy.soft.sum()),
    }


def dispersed_summary(flight) -> dict:
    """One dispersed flight: its success, and per constraint the problem has, the starts breaking it
    (beyond the env's tolerances, as the score counts) and the deepest violation (m, m/s, m)."""
    out = {"success_rate": float(flight.is_success.mean()), "breaking_starts": {}, "deepest": {}}
    for name, rate, depth in (
        ("keep_out", flight.violation_rate, flight.keep_out_depth),
        ("speed", flight.speed_violation_rate, flight.speed_depth),
        ("cone", flight.cone_violation_rate, flight.cone_depth),
    ):
        if rate is not None and depth is not None:
            out["breaking_starts"][name] = int((rate > 0).sum())
            out["deepest"][name] = float(depth.max())
    broken = [
        rate > 0
        for rate in (flight.violation_rate, flight.speed_violation_rate, flight.cone_violation_rate)
        if rate is not None
    ]
    out["violating_starts"] = int(np.any(broken, axis=0).sum()) if broken else 0
    return out


def violation_rates(task: Task, flight) -> dict | None:
    """The share of steps breaking each constraint the task has, over the starts."""
    if not task.docking:
        return None
    rates = {"keep_out": float(flight.violation_rate.mean())}
    if flight.speed_violation_rate is not None:
        rates["speed"] = float(flight.speed_violation_rate.mean())
    if flight.cone_violation_rate is not None:
        rates["cone"] = float(flight.cone_violation_rate.mean())
    return rates


def time_per_step(task: Task, entry: Entry, seed: int | None) -> dict:
    """p50 and p99 [µs] of one step's compute for one start: the navigation filter's update and
    thrust correction (rows on it), the policy on one observation, then the filter on its action
    (docking rows with a CBF). MPC's solve is timed inside it, without the
    condensed model of each remaining horizon, which is built once and shared."""
    n = min(2 if entry.starts else TIMED_STARTS, len(task.held_out.starts))
    samples, plans = [], []
    for i in range(n):
        policy = entry.make(seed)
        calls: list[tuple[float, np.ndarray, np.ndarray]] = []

        def timed(obs, policy=policy, calls=calls):
            started = time.perf_counter()
            action = policy(obs)
            calls.append((time.perf_counter() - started, obs, np.asarray(action)))
            return action

        held = task.held_out.take(i + 1)
        flight = fly(
            task.problem,
            timed,
            held.starts[i : i + 1],
            held.goals[i : i + 1] if task.docking else None,
            cbf_margin=task.problem.margin if entry.cbf else None,
            cbf_bounds=task.bounds_at(entry.k_sigma) if entry.robust else None,
            navigation=task.bounds if entry.navigation else None,
            cbf_navigation=entry.cbf_navigation,
            cbf_stop_line=entry.stop_line,
        )
        sigmas = [None] * len(calls)  # the navigation filter's, where it sizes the robust filter
        if isinstance(policy, RecedingHorizon):
            seconds = np.array(policy.solve_seconds)
        else:
            seconds = np.array([c[0] for c in calls])
        if entry.navigation:  # its update on each step's measurement (nominal: the state) and G_hat^-1 u
            navigator = NavigationFilter(task.problem, task.bounds)
            navigator.start(np.ones(1, dtype=bool), flight.states[:, 0])
            for k in range(len(calls)):
                started = time.perf_counter()
                if k:
                    navigator.step(flight.thrust[:, k - 1], flight.states[:, k])
                    np.linalg.solve(navigator.thrust_gain(), flight.thrust[:, k, :, None])
                if entry.cbf_navigation == "covariance":
                    sigmas[k] = navigator.sigma()
                seconds[k] += time.perf_counter() - started
        if entry.cbf and not isinstance(policy, RecedingHorizon):
            for k, (_, _, action) in enumerate(calls):
                state, goal = flight.states[:, k], flight.goals
                started = time.perf_counter()
                filter_actions(
                    np.clip(action, -1.0, 1.0),
                    state,
                    task.problem,
                    task.problem.margin,
                    goal,
                    task.bounds_at(entry.k_sigma) if entry.robust else None,
                    sigmas[k],
                    entry.stop_line,
                )
                seconds[k] += time.perf_counter() - started
        samples.append(seconds)
        if isinstance(policy, TubeMPC):
            plans.extend(policy.plan_seconds)
    seconds = np.concatenate(samples) * 1e6
    return {
        "p50": float(np.percentile(seconds, 50)),
        "p99": float(np.percentile(seconds, 99)),
        "steps": len(seconds),
        # the tube MPC's one plan per episode, inside its first step's time above
        **(
            {"plan_s_median": float(np.median(plans)), "plans": len(plans), "mean": float(seconds.mean())}
            if plans
            else {}
        ),
    }


# ------------------------------------------------------------------------------------ output


def row(task: Task, entry: Entry, measured: dict, timing: dict | None) -> dict:
    """The leaderboard.json row: the issue's keys first, then what explains them."""
    per_seed = measured["per_seed"]
    metric = task.train.METRIC

    def mean(key):
        return float(np.mean([r["metrics"][key] for r in per_seed]))

    distances = np.concatenate([r["terminal_distance"] for r in per_seed])
    values = [r["metrics"][metric] for r in per_seed]
    rates = [r["violation_rates"] for r in per_seed]
    out = {
        "task": task.name,
        "controller": entry.name,
        "split": "test",
        "n_starts": len(per_seed[0]["terminal_distance"]),
        "split_starts": task.train.N_TEST,  # the whole split's size (n_starts may be its first few)
        # the identity of the starts flown (cwh_envs.splits): the same on every machine that flies them
        "split_id": task.held_out.take(len(per_seed[0]["terminal_distance"])).starts_key,
        "metric": float(np.mean(values)),
        "success_rate": mean("success_rate"),
        "violation_rate": None
        if rates[0] is None
        else {k: float(np.mean([r[k] for r in rates])) for k in rates[0]},
        "p99_terminal_distance": float(np.percentile(distances, 99)),
        "max_terminal_distance": float(distances.max()),
        "delta_v_ratio": mean("delta_v_ratio"),
        "energy_ratio": mean("effort_ratio"),
        "us_per_step": timing,
        "dispersed_success_rate": float(np.mean([r["dispersed_success_rate"] for r in per_seed])),
        "metric_name": metric,
        "median_terminal_distance": float(np.median(distances)),
        "strict_feasible": [r["metrics"]["strict_feasible"] for r in per_seed] if task.docking else None,
        "cbf": entry.cbf,
        "kind": entry.kind,
        "source": entry.source,
    }
    if entry.kind != "classical":
        out |= {
            "seeds": [r["seed"] for r in per_seed],
            "metric_per_seed": values,
            "metric_std": float(np.std(values, ddof=1)) if len(values) > 1 else None,
        }
    if entry.rl:  # the budget, and rliable's summary over the seeds of the metric flown here
        out |= {
            "env_steps": entry.rl["env_steps"],
            "iqm": _rl_baselines().iqm_interval(values),
            "command": entry.rl["command"],
        }
    if entry.kind in ("bc", "rl-family"):
        campaign = (
            family_best_campaign(task.name)
            if entry.name == "family best (BC)"
            else entry.source.split(" ")[0]
        )
        if campaign:
            out["produced_by"] = produced_by(campaign)
    if entry.config:
        out["config"] = entry.config
    if entry.time_budget:
        out["time_budget"] = entry.time_budget
    if "subset" in per_seed[0]:
        out["subset"] = per_seed[0]["subset"]
    for counts in ("mpc", "mpc_dispersed", "plans"):
        if counts in per_seed[0]:
            out[counts] = per_seed[0][counts]
    if "dispersed" in per_seed[0]:  # flown at every level (issue 58); older rows keep their 1-sigma success
        out["dispersed"] = {
            level: dispersed_over_seeds([r["dispersed"][level] for r in per_seed])
            for level in DISPERSION_LEVELS
        }
    if entry.robust or entry.sized:
        out["robust_bounds"] = {"from": "1-sigma DISPERSIONS", "k_sigma": entry.k_sigma}
        if entry.cbf_navigation == "covariance":
            out["robust_bounds"]["navigation_margins"] = "the navigation filter's covariance"
        if entry.stop_line:
            out["robust_bounds"]["stop_line"] = True
    if task.docking:
        out |= flight(task)
    return out


def plans_cell(counts: dict) -> str:
    """How a tube MPC row's plans were found, in words (cwh_envs.tube_mpc.PLANS), the ways used only."""
    words = {
        "cold": "solved cold",
        "warm": "warm-started from the corridor's plan",
        "boxed": "from the start box",
        "soft": "soft",
        "corridor": "untightened (the corridor's plan)",
        "law": "none (the law flew)",
    }
    return ", ".join(f"{n} {words[way]}" for way, n in counts.items() if n)


def dispersed_over_seeds(summaries: list[dict]) -> dict:
    """A dispersion level over the seeds: success and breaking starts as the mean, each constraint's
    deepest violation as the worst of any seed."""
    return {
        "success_rate": float(np.mean([s["success_rate"] for s in summaries])),
        "violating_starts": float(np.mean([s["violating_starts"] for s in summaries])),
        "breaking_starts": {
            name: float(np.mean([s["breaking_starts"][name] for s in summaries]))
            for name in summaries[0]["breaking_starts"]
        },
        "deepest": {name: max(s["deepest"][name] for s in summaries) for name in summaries[0]["deepest"]},
        **({"mpc": summaries[0]["mpc"]} if "mpc" in summaries[0] else {}),
        **({"plans": summaries[0]["plans"]} if "plans" in summaries[0] else {}),
    }


def flight(task: Task) -> dict:
    """What a docking row's numbers depend on beyond its policy (issue 58): the filter of a dispersed
    flight acts on the navigation estimate (``fly``'s default), and the cone is scored with the
    problem's capture envelope."""
    out = {"dispersed_filter_sees": "estimate"}
    if task.problem.approach_cone is not None:
        out["capture_radius"] = task.problem.capture_radius
    return out


def fmt(value, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and (abs(value) >= 1e4 or (0 < abs(value) < 1e-3)):
        return f"{value:.{digits - 1}e}"
    return f"{value:.{digits}g}"


def markdown(rows: list[dict]) -> str:
    lines = []
    for task in dict.fromkeys(r["task"] for r in rows):
        block = [r for r in rows if r["task"] == task]
        n, whole = max(r["n_starts"] for r in block), max(r.get("split_starts", 0) for r in block)
        starts = f"the first {n} of its {whole} starts" if whole > n else f"{n} starts"
        lines += [
            f"### {task} (test split, {starts}; metric: {block[0]['metric_name']}, lower is better)",
            "",
            "| controller | metric | success | violation rate (per constraint) | p99 / max terminal distance [m] "
            "| Δv / expert | energy / expert | µs per step (p50 / p99) | dispersed success 1σ / 3σ "
            "| starts broken under dispersions (deepest) | note |",
            "|---|---:|---:|---|---:|---:|---:|---:|---:|---|---|",
        ]
        for r in block:
            metric = fmt(r["metric"])
            if r.get("metric_std") is not None:
                metric += f" ± {fmt(r['metric_std'], 2)} (n={len(r['seeds'])})"
            rates = (
                "-"
                if r["violation_rate"] is None
                else ", ".join(f"{k} {v:.2%}" for k, v in r["violation_rate"].items())
            )
            timing = (
                "-"
                if r["us_per_step"] is None
                else f"{fmt(r['us_per_step']['p50'])} / {fmt(r['us_per_step']['p99'])}"
            )
            notes = []
            if r["n_starts"] != max(x["n_starts"] for x in block):
                notes.append(f"first {r['n_starts']} starts")
            if r.get("mpc"):
                m = r["mpc"]
                of = f" of {m['solves']}" if "solves" in m else ""  # rows measured before the count
                notes.append(
                    f"{m['infeasible_resolves']}{of} re-solves failed ({m['fallbacks']} flown on the "
                    f"previous plan or the law, {m.get('soft_replans', 0)} re-planned soft)"
                )
            if r.get("mpc_dispersed"):
                m = r["mpc_dispersed"]
                notes.append(f"dispersed: {m['infeasible_resolves']} of {m['solves']} re-solves failed")
            for level, flown in (r.get("dispersed") or {}).items():
                if "mpc" in flown:  # how often a disturbed state left MPC's re-solve without an answer
                    m = flown["mpc"]
                    notes.append(
                        f"{level.replace('sigma', 'σ')}: {m['infeasible_resolves']} of {m['solves']} re-solves "
                        f"failed ({m['fallbacks']} flown on the previous plan or the law)"
                    )
            if r.get("plans"):
                notes.append(f"plans: {plans_cell(r['plans'])}")
            for level, flown in (r.get("dispersed") or {}).items():
                if flown.get("plans"):
                    notes.append(f"{level.replace('sigma', 'σ')} plans: {plans_cell(flown['plans'])}")
            if (r["us_per_step"] or {}).get("plan_s_median") is not None:
                t = r["us_per_step"]
                notes.append(
                    f"one plan per episode, {t['plan_s_median']:.2g} s (median): {fmt(t['mean'])} µs a step "
                    "amortised over the episode"
                )
            if r.get("iqm"):
                ci = r["iqm"]["ci95"]
                notes.append(
                    f"{r['env_steps']:,} env steps a seed; IQM {fmt(r['iqm']['iqm'])} [{fmt(ci[0])}, {fmt(ci[1])}]"
                )
            if r["strict_feasible"] is not None:
                notes.append(f"strict-feasible {sum(r['strict_feasible'])}/{len(r['strict_feasible'])}")
            if "split_id" not in r:  # flown before rows recorded it (issue 57): results/splits/README.md
                notes.append("split not recorded (flown before issue 57)")
            if r["cbf"] and "dispersed_filter_sees" not in r:  # flown before issue 58
                notes.append("dispersed with the filter fed the true state (flown before issue 58)")
            if "cone" in (r["violation_rate"] or {}) and "capture_radius" not in r:
                notes.append("cone scored with its apex on the port (before issue 58's capture envelope)")
            levels, dispersed = r.get("dispersed"), dispersed_cell(r)
            if levels is None:
                notes.append("3σ not flown (measured before issue 58)")
                broken = "-"
            else:
                broken = "<br>".join(
                    f"{level.replace('sigma', 'σ')}: {broken_cell(levels[level])}"
                    for level in DISPERSION_LEVELS
                )
            name = r["controller"] + (f"<br><sub>{r['produced_by']}</sub>" if r.get("produced_by") else "")
            lines.append(
                f"| {name} | {metric} | {r['success_rate']:.1%} | {rates} | "
                f"{fmt(r['p99_terminal_distance'])} / {fmt(r['max_terminal_distance'])} | {fmt(r['delta_v_ratio'])} | "
                f"{fmt(r['energy_ratio'])} | {timing} | {dispersed} | {broken} | {'; '.join(notes)} |"
            )
        lines.append("")
    return "\n".join(lines)


# The README's table per task (summary): the best learned policy beside MPC and the closed-form law (and
# the robust filter's rows, on docking), and the best long RL row; PD and the rest are in
# results/leaderboard.md.
SUMMARY_ROWS = (
    "family best (BC)",
    "robust hand recipe",
    "MPC",
    "closed-form feedback",
    "routed feedback",
    "robust CBF",
)


def summarised(controller: str) -> bool:
    """Whether a row is in the README's summary: those SUMMARY_ROWS name, less the robust filter on the
    raw measurement where its row on the navigation filter (flight software's view) stands beside it,
    and the covariance-sized one without its stop line where the row with it does; every row stays
    in results/leaderboard.md."""
    raw_robust = "robust CBF" in controller and "navigation filter" not in controller
    unlined = "covariance-sized robust CBF + " in controller
    return any(k in controller for k in SUMMARY_ROWS) and not raw_robust and not unlined


SUMMARY_START, SUMMARY_END = "<!-- leaderboard summary: start -->", "<!-- leaderboard summary: end -->"


def summary(rows: list[dict]) -> str:
    """The README's leaderboard: one compact table per task, written from leaderboard.json (the
    README holds it between SUMMARY_START and SUMMARY_END; a test keeps the two equal)."""
    lines = []
    for task in dict.fromkeys(r["task"] for r in rows):
        block = [r for r in rows if r["task"] == task and summarised(r["controller"])]
        trained = [r for r in rows if r["task"] == task and r["kind"] == "rl"]
        best = min(trained, key=lambda r: r["metric"]) if trained else None
        if (
            best and best not in block
        ):  # the best long RL row (issue 60); the others are in results/leaderboard.md
            block.append(best)
        block.sort(key=lambda r: r["kind"] == "classical")  # the learned row first, then as ranked
        n = max(r["n_starts"] for r in block)
        lines += [
            f"**{task}** ({block[0]['metric_name']}, lower is better; sealed test split, {n} starts)",
            "",
            "| controller | metric | success | dispersed success 1σ / 3σ | energy / expert | µs per step |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for r in block:
            dispersed = dispersed_cell(r)
            starts = f" (first {r['n_starts']} starts)" if r["n_starts"] != n else ""
            lines.append(
                f"| {r['controller']}{starts} | {fmt(r['metric'])} | {r['success_rate']:.1%} | {dispersed} "
                f"| {fmt(r['energy_ratio'])} | {fmt(r['us_per_step']['p50'])} |"
            )
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def dispersed_cell(r: dict) -> str:
    """``99.9% / 22.3%``: the row's dispersed success at each level; ``-`` at 3σ for a row flown
    before issue 58 (one level only)."""
    levels = r.get("dispersed")
    if levels is None:
        return f"{r['dispersed_success_rate']:.1%} / -"
    return " / ".join(f"{levels[level]['success_rate']:.1%}" for level in DISPERSION_LEVELS)


def write_readme_summary(readme: Path, text: str) -> None:
    """Replace the README's leaderboard tables (between SUMMARY_START and SUMMARY_END) by ``text``."""
    page = readme.read_text(encoding="utf-8")
    head, rest = page.split(SUMMARY_START + "\n", 1)
    tail = rest.split(SUMMARY_END, 1)[1]
    readme.write_text(f"{head}{SUMMARY_START}\n{text}{SUMMARY_END}{tail}", encoding="utf-8")


UNITS = {"keep_out": "m", "speed": "m/s", "cone": "m"}


def broken_cell(level: dict) -> str:
    """``speed 1 (1.7e-04 m/s)``: each constraint some start broke, how many starts (mean over
    seeds) and the deepest violation; "none" where every start kept every constraint."""
    parts = [
        f"{name} {fmt(starts)} ({fmt(level['deepest'][name])} {UNITS[name]})"
        for name, starts in level["breaking_starts"].items()
        if starts > 0
    ]
    return ", ".join(parts) if parts else ("none" if level["breaking_starts"] else "-")


def plot(rows: list[dict], task: str, path: Path) -> None:
    """Metric against energy over the expert's, log-log; marker area grows with the compute per step."""
    block = [r for r in rows if r["task"] == task]
    figure = Figure(figsize=(8.5, 5.5), layout="constrained")
    ax = figure.subplots()
    floor = 1e-9  # the open-loop expert's ~1e-13 would flatten the rest: drawn at the floor
    n = max(r["n_starts"] for r in block)
    for i, r in enumerate(block):
        micro = r["us_per_step"]["p50"] if r["us_per_step"] else 1.0
        area = 30 * (1 + np.log10(max(micro, 1.0))) ** 2
        x, y = r["energy_ratio"], max(r["metric"], floor)
        label = f"{r['controller']}: {fmt(r['metric'])}, {fmt(micro)} µs/step"
        if r["n_starts"] != n:
            label += f" (first {r['n_starts']} starts)"
        ax.scatter([x], [y], s=area, color=f"C{i % 10}", alpha=0.6, edgecolor="k", label=label, zorder=3)
        ax.annotate(
            r["controller"], (x, y), xytext=(6, 4 + 8 * (i % 2)), textcoords="offset points", fontsize=7
        )
        if r.get("metric_per_seed"):  # each seed's value as a tick beside the mean
            seeds = np.maximum(r["metric_per_seed"], floor)
            ax.scatter([x] * len(seeds), seeds, s=60, color=f"C{i % 10}", marker="_", zorder=4)
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="energy / open-loop expert's (Σ|u|²dt, summed over the same starts)",
        ylabel=f"{block[0]['metric_name']} (lower is better; floor {floor:g})",
    )
    ax.set_title(f"{task}: {n} sealed test starts\nmarker area grows with the compute per step", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.savefig(path, dpi=100)


# -------------------------------------------------------------------------------------- main


def main(argv=None) -> None:
    args = parse_args(argv)
    import torch

    torch.set_num_threads(1)
    out_json = args.out / "leaderboard.json"
    kept = json.loads(out_json.read_text(encoding="utf-8")) if out_json.exists() else []
    rows = [
        r for r in kept if r["task"] not in args.tasks or (args.rows and r["controller"] not in args.rows)
    ]
    for name in args.tasks:
        task = Task.load(name, args.starts)
        for entry in entries(task, args.work, args.seeds, args.mpc_starts):
            if args.rows and entry.name not in args.rows:
                continue
            cache = args.work / "rows" / f"{name}-n{len(task.held_out.starts)}" / f"{slug(entry.name)}.json"
            seeds = entry.rl["seeds"] if entry.rl else args.seeds
            key = {
                "seeds": seeds if entry.kind != "classical" else None,
                # an RL row is the checkpoint it flies: a longer run of the same row is a new measurement
                **({"checkpoint_steps": entry.rl["checkpoint_steps"]} if entry.rl else {}),
                "config": entry.config,
                "starts": entry.starts,
                # only where one is granted: the rows measured before budgets stay cached
                **({"time_budget": entry.time_budget} if entry.time_budget else {}),
                # how a docking row is scored and flown dispersed (issue 58): a row cached before is stale
                **({"flight": flight(task)} if task.docking else {}),
                "dispersion_levels": DISPERSION_LEVELS,
                **(
                    {"robust": dataclasses.asdict(task.bounds_at(entry.k_sigma))}
                    if entry.robust or entry.sized
                    else {}
                ),
                **({"cbf_navigation": entry.cbf_navigation} if entry.cbf_navigation != "bounds" else {}),
                **({"stop_line": True} if entry.stop_line else {}),
            }
            cached = (
                json.loads(cache.read_text(encoding="utf-8")) if cache.exists() and not args.fresh else {}
            )
            if cached.get("key") != key:
                print(f"[fly] {name}: {entry.name} ...", flush=True)
                started = time.perf_counter()
                cached = {"key": key, "measured": measure(task, entry, args.seeds)}
                print(f"[fly] {name}: {entry.name}: {time.perf_counter() - started:.0f} s", flush=True)
            if args.retime or "timing" not in cached:
                cached["timing"] = time_per_step(task, entry, seeds[0] if entry.kind != "classical" else None)
            cache.parent.mkdir(parents=True, exist_ok=True)
            cache.write_text(json.dumps(cached), encoding="utf-8")
            rows.append(row(task, entry, cached["measured"], cached["timing"]))
            r = rows[-1]
            print(
                f"[row] {name}: {entry.name}: {r['metric_name']} {fmt(r['metric'])}, success {r['success_rate']:.1%}, "
                f"p99/max {fmt(r['p99_terminal_distance'])}/{fmt(r['max_terminal_distance'])}, "
                f"energy x{fmt(r['energy_ratio'])}, {fmt(r['us_per_step']['p50'])} µs/step",
                flush=True,
            )
    rows.sort(key=lambda r: (TASKS.index(r["task"]), rank(r["controller"])))
    args.out.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(rows, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    (args.out / "leaderboard.md").write_text(markdown(rows), encoding="utf-8")
    (args.out / "leaderboard-summary.md").write_text(summary(rows), encoding="utf-8")
    if args.out.resolve() == (ROOT / "results").resolve():  # the README shows the same tables
        write_readme_summary(ROOT / "README.md", summary(rows))
    for task in dict.fromkeys(r["task"] for r in rows):
        plot(rows, task, args.out / f"leaderboard_{task}.png")
    print(f"wrote {out_json}, leaderboard.md and one PNG per task to {args.out}")


if __name__ == "__main__":
    main()
