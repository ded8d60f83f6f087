"""Measured seed noise (paper Eq. noisefloor): the baseline configuration over K fresh seeds.

The result is a property of the family, so it is written into the family's ledger (ledger.json
beside family.json: ``seed_noise``), and also into a campaign's audit.json when the measurement is
part of its audit. Runs are logged as they finish; a re-run skips the seeds already measured, and a larger
``k`` extends the same seed list (the plan is deterministic). For a family with a sealed test
split the same runs are scored on it too: ``seed_noise["test"]`` holds that split's mean, std and
values (never shown to a proposer: autoresearch.family.search_view). ``seed_noise["pinned"]`` holds
what the numbers depend on (the baseline configuration, and the code of train.py and prepare.py
without their docstrings and comments), so that an audit of a changed family measures the noise
again instead of gating on stale numbers, and a corrected docstring does not.
"""

from __future__ import annotations

import ast
import hashlib
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from autoresearch import ledger
from autoresearch.audit import stats
from autoresearch.audit.inputs import AuditedCampaign, AuditError, Rereading
from autoresearch.audit.seeds import fresh_seeds, used_seeds
from autoresearch.audit.trials import Trial, run_trials
from autoresearch.campaign import portable_path
from autoresearch.campaign.audit_log import read_audit, write_step
from autoresearch.execution.executors import Executor
from autoresearch.family import Family
from autoresearch.ledger import LEDGER_FILE
from autoresearch.provenance import family_hashes
from autoresearch.splits import SPLIT_IDS, Score, Split, recorded_split_ids, split_mismatches

STEP = "noise"
PINNED_FILES = ("train.py", "prepare.py")  # the baseline's code and data; program.md is prose


def default_noise_dir(family: Family) -> Path:
    """Where a stand-alone measurement keeps its runs: never inside the family directory."""
    return Path("runs") / f"noise-{family.name}"


def measure_noise(
    family: Family,
    executor: Executor,
    *,
    k: int = 10,
    campaign: AuditedCampaign | None = None,
    out_dir: Path | None = None,
    timeout: float = 3600.0,
) -> dict[str, Any]:
    """Run the baseline at ``k`` fresh seeds; write and return the family's ``seed_noise``."""
    if k < 2:
        raise AuditError(f"--seeds {k}: seed noise needs K >= 2 seeds (one run has no spread to measure)")
    budget = None  # a campaign's time budget: its baseline is measured as the campaign ran it
    if campaign is not None:
        root, timeout, budget = campaign.step_dir(STEP), campaign.audit_timeout, campaign.time_budget
        used = used_seeds(family.default_seed, None, [campaign.root], skip_step=STEP)
    else:
        root, used = (out_dir or default_noise_dir(family)), {family.default_seed}
    seeds = fresh_seeds(used, k)
    baseline = family.baseline_config
    trials = [Trial(f"noise-s{seed}", baseline, seed) for seed in seeds]
    earlier = Rereading(None, ())  # a campaign's finished noise step, kept if this run only re-reads it
    if campaign is not None:
        earlier = campaign.rereading(STEP, root / "noise.jsonl")
        write_step(
            campaign.root, STEP, {"status": "running", "seeds": seeds, "runs_dir": portable_path(root)}
        )
    rows = run_trials(family, trials, executor, root / "noise.jsonl", root, timeout, time_budget=budget)
    ok = [r for r in rows if r.ok]
    failed = [{"seed": r.seed, "reason": r.reason} for r in rows if not r.ok]
    if len(ok) < 2:
        raise AuditError(
            f"seed noise: only {len(ok)} of {k} baseline runs succeeded (K >= 2 needed); "
            f"failures: {failed}; re-run to retry them"
        )
    # run_trials refused any run scored off the family's pinned splits, so these agree with its pins
    split_ids = recorded_split_ids(ok[0].final_metric)
    search = _spread([r.scores.search for r in ok])
    sealed = {Split.TEST.value: _spread([r.scores.test for r in ok])} if family.has_test_split else {}
    noise = {
        **search,
        "seeds": [r.seed for r in ok],
        "metric": family.metric,
        "measured_at": earlier.kept("measured_at", datetime.now(timezone.utc).isoformat(timespec="seconds")),
        "runs_dir": portable_path(root),
        "failed": failed,
        "pinned": pins(family),
        **({SPLIT_IDS: split_ids} if split_ids else {}),
        **({"time_budget": budget} if budget is not None else {}),
        **sealed,
    }
    ledger.update(family.path, lambda registry, old: (old.measured(noise), None))
    if campaign is not None:
        write_step(
            campaign.root,
            STEP,
            {
                "status": "done",
                "source": "measured",
                **noise,
                "provenance": earlier.kept("provenance", campaign.provenance),
            },
        )
    return noise


def _spread(scores: list[Score]) -> dict[str, Any]:
    """The seed noise on one split: Eq. noisefloor over the runs' scores there."""
    floor = stats.noise_floor([score.metric for score in scores])
    return {
        "mean": floor.mean,
        "std": floor.std,
        "k": floor.k,
        "values": [score.metric for score in scores],
        "n_feasible": sum(score.feasible for score in scores),
    }


CODE_HASH = "code"  # pinned["hash"]: PINNED_FILES hashed as code, without docstrings and comments


def code_hash(path: Path) -> str | None:
    """sha256 (16 hex digits) of a Python file's code: its syntax tree without docstrings, so that
    comments and prose (a docstring corrected to match a constant) leave the noise measured on it
    standing, while any change to what runs stales it. A file that does not parse hashes its bytes."""
    if not path.is_file():
        return None
    source = path.read_bytes()
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return hashlib.sha256(source).hexdigest()[:16]
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (
            isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and body
            and isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        ):
            node.body = body[1:] or [ast.Pass()]
    return hashlib.sha256(ast.dump(tree).encode()).hexdigest()[:16]


def pins(family: Family) -> dict[str, Any]:
    """What the seed noise depends on, as it is now: the baseline configuration and the code of
    PINNED_FILES (:func:`code_hash`)."""
    files = {name: code_hash(family.path / name) for name in PINNED_FILES}
    return {"baseline": family.baseline_config, "files": files, "hash": CODE_HASH}


def _pinned_now(family: Family, pinned: dict[str, Any]) -> dict[str, str | None]:
    """PINNED_FILES hashed as ``pinned`` hashed them: as code, or (noise pinned before that) as bytes."""
    if pinned.get("hash") == CODE_HASH:
        return pins(family)["files"]
    hashes = family_hashes(family.path)
    return {name: hashes[name] for name in PINNED_FILES}


def stale_noise(family: Family) -> list[str]:
    """How the family differs from what its seed noise was measured on, one line each: its files and
    baseline (unless the noise predates pinning them), and the splits it was scored on when the family
    pins them (noise that records none was scored before they were pinned)."""
    noise = family.seed_noise or {}
    measured_on = (Split.SEARCH, Split.TEST) if family.has_test_split else (Split.SEARCH,)
    found = [
        f"seed noise on the {line}"
        for line in split_mismatches(noise.get(SPLIT_IDS) or {}, family.split_ids, measured_on)
    ]
    pinned = noise.get("pinned")
    if not isinstance(pinned, dict):
        return found
    files = pinned.get("files") or {}
    found += [
        f"{name}: sha256 {files.get(name)} -> {sha}"
        for name, sha in _pinned_now(family, pinned).items()
        if files.get(name) != sha
    ]
    if pinned.get("baseline") != family.baseline_config:
        found.append("the baseline configuration")
    return found


def record_existing_noise(campaign: AuditedCampaign) -> dict[str, Any]:
    """The audit's noise step when the family already has its seed noise: record, do not re-measure."""
    noise = campaign.family.seed_noise
    if not noise:
        raise AuditError(f"family {campaign.family.name!r} has no seed noise to record")
    recorded = read_audit(campaign.root).get(STEP) or {}
    if {k: recorded.get(k) for k in noise} != noise:  # keep "measured" if this audit measured it
        part = {"status": "done", "source": LEDGER_FILE, **noise, "provenance": campaign.provenance}
        write_step(campaign.root, STEP, part)
    return noise
