"""A family's protocols (family.json ``protocols``, ``loop --protocol NAME``): a named restriction of
its search space, e.g. the paper's space inside one that grew an algorithm axis."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from loop_helpers import TOY_FAMILY

from autoresearch.campaign import CampaignMeta
from autoresearch.family import Family, family_problems
from autoresearch.proposers.base import ProposerContext
from autoresearch.proposers.random_search import RandomProposer
from autoresearch.space import ValidationError

ROOT = Path(__file__).resolve().parents[1]


def context(iteration: int) -> ProposerContext:
    return ProposerContext(
        iteration=iteration,
        warnings=(),
        program="",
        registry={},
        random_arm_summary=None,
        history=(),
        current_values={},
        running=(),
    )


@pytest.mark.parametrize("name", ["rendezvous", "docking", "docking-constrained"])
def test_the_paper_protocol_holds_the_algorithm_axis_at_the_baseline(name):
    family = Family.load(ROOT / "families" / name)
    paper = family.under_protocol("paper")
    algorithm = [p for p, spec in family.registry["search_space"].items() if spec["axis"] == "algorithm"]
    assert algorithm and paper.registry["protocol"] == "paper"
    assert paper.space.validate_full(family.baseline_config) == family.space.validate_full(
        family.baseline_config
    )
    with pytest.raises(ValidationError):
        paper.space.validate({"POLICY_FORM": "residual"})
    family.space.validate({"POLICY_FORM": "residual"})  # the whole space allows it
    proposer = RandomProposer(paper.search_registry(), seed=3, space="bounds")
    drawn = [proposer.propose(context(i)).overrides for i in range(2, 30)]
    for overrides in drawn:
        assert all(overrides[p] == family.baseline_config[p] for p in algorithm)
    if name == "rendezvous":
        assert max(o["N_DEMOS"] for o in drawn) <= 1024 < family.space.params["N_DEMOS"].high
    assert family.under_protocol(None) is family


def bad_copy(tmp_path: Path, protocols) -> Path:
    family = tmp_path / "toy"
    shutil.copytree(TOY_FAMILY, family)
    registry = json.loads((family / "family.json").read_text())
    registry["protocols"] = protocols
    (family / "family.json").write_text(json.dumps(registry))
    return family


def test_a_malformed_protocol_is_a_problem_of_the_family(tmp_path):
    registry = json.loads((TOY_FAMILY / "family.json").read_text())
    param, spec = next(iter(registry["search_space"].items()))
    cases = {
        "unknown axis": {"p": {"exclude_axes": ["no-such-axis"]}},
        "unknown key": {"p": {"keep": []}},
        "limit not a number": {"p": {"limits": {"loss": "low"}}},
        "limits not an object": {"p": {"limits": [1.0]}},
        "baseline outside": {
            "p": {
                "bounds": {
                    param: {"choices": ["nothing like it"]}
                    if "choices" in spec
                    else {"low": spec["high"], "high": spec["high"]}
                }
            }
        },
    }
    for why, protocols in cases.items():
        problems = family_problems(bad_copy(tmp_path / why.replace(" ", "-"), protocols))
        assert any("protocols.p" in problem for problem in problems), (why, problems)


def test_limits_belong_in_a_protocol(tmp_path):
    family = bad_copy(tmp_path, {})
    registry = json.loads((family / "family.json").read_text())
    (family / "family.json").write_text(json.dumps({**registry, "limits": {"loss": 1.0}}))
    assert any("'limits' belongs in a protocol" in problem for problem in family_problems(family))


@pytest.mark.parametrize(("name", "limit"), [("docking", 1.5), ("docking-constrained", 2.0)])
def test_the_fuel_protocol_holds_a_feasible_run_to_its_energy_limit(name, limit):
    """Under ``fuel`` a run counts as feasible only when its strict gate is met and it spends at most
    ``limit`` x the expert's energy; the limit is one more graded constraint, and a run that does not
    report the field fails it. The space is the family's whole space."""
    family = Family.load(ROOT / "families" / name)
    fuel = family.under_protocol("fuel")
    assert fuel.limits == {"effort_ratio": limit} and family.limits == {}
    assert fuel.registry["search_space"] == family.registry["search_space"]
    assert fuel.search_registry()["limits"] == {"effort_ratio": limit}
    graded = {"success_shortfall": -0.2, "violation_rate": 0.0, "clearance_deficit": -0.5}
    run = {"strict_feasible": True, "constraints": graded, "effort_ratio": limit + 0.25}
    assert family.is_feasible(run) and not fuel.is_feasible(run)
    assert fuel.constraints(run) == {**graded, "effort_ratio_over_limit": pytest.approx(0.25)}
    assert fuel.is_feasible({**run, "effort_ratio": limit})
    assert not fuel.is_feasible({**run, "strict_feasible": False, "effort_ratio": 1.0})
    assert (
        not fuel.is_feasible({"strict_feasible": True})
        and fuel.constraints({"strict_feasible": True}) is None
    )


def test_limits_without_a_constraints_field_grade_the_gate_as_zero_or_one(tmp_path):
    path = bad_copy(tmp_path, {"p": {"limits": {"loss": 2.0}}})
    registry = json.loads((path / "family.json").read_text())
    del registry["constraints_field"]
    (path / "family.json").write_text(json.dumps(registry))
    family = Family.load(path).under_protocol("p")
    field = family.feasibility_field
    assert family.constraints({field: True, "loss": 1.5}) == {field: 0.0, "loss_over_limit": -0.5}
    assert family.constraints({field: False, "loss": 2.5}) == {field: 1.0, "loss_over_limit": 0.5}


def test_loop_refuses_an_undeclared_protocol_in_one_line(tmp_path):
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "autoresearch",
            "loop",
            "--family",
            str(TOY_FAMILY),
            "--proposer",
            "random",
            "--protocol",
            "paper",
            "--campaign",
            str(tmp_path / "c"),
            "--max-runs",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip().endswith("declares no such protocol (it declares none)")
    assert not (tmp_path / "c" / "campaign.json").exists()


def test_a_campaign_keeps_its_protocol_and_the_audit_opens_the_family_under_it(tmp_path):
    family = Family.load(ROOT / "families" / "docking")
    meta = CampaignMeta.new(family, "random", {"protocol": "paper"})
    root = tmp_path / "campaign"
    root.mkdir()
    meta.write(root)
    opened = CampaignMeta.read(root).open_family(root)
    assert opened.registry["protocol"] == "paper"
    assert opened.space.params["N_DEMOS"].choices == (32, 64, 128, 256)
