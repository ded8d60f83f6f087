"""campaign.json has one owner (autoresearch.loop.campaign.CampaignMeta): every writer (the loop, each
repeat of a group, the audit's random arm) writes the same keys, paths inside the working directory are
written relative to it, and files of older writers still read."""

from __future__ import annotations

import json

import pytest
from audit_support import AUDIT_FAMILY, P1, ScriptedProposer, copy_family, run_campaign
from loop_helpers import copy_toy

from autoresearch.audit.inputs import open_campaign
from autoresearch.audit.random_arm import run_random_arm
from autoresearch.campaign import CampaignError, CampaignMeta, portable_path
from autoresearch.cli import main
from autoresearch.execution.executors import LocalExecutor
from autoresearch.journal import read_json

KEYS = {"family", "family_name", "proposer", "settings", "created", "sessions", "family_dir"}


def test_portable_path_is_relative_inside_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "families" / "toy").mkdir(parents=True)
    assert portable_path(tmp_path / "families" / "toy") == "families/toy"
    assert portable_path("families/../families/toy") == "families/toy"
    outside = tmp_path.parent / "elsewhere"
    assert portable_path(outside) == str(outside.resolve())


def test_every_writer_writes_the_same_record_with_relative_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    toy = copy_toy(tmp_path)
    common = ["--family", str(toy), "--proposer", "random", "--max-iters", "2"]
    assert main(["loop", *common, "--campaign", "single"]) == 0
    assert main(["loop", *common, "--repeats", "2", "--campaign", "group"]) == 0
    family = copy_family(AUDIT_FAMILY, tmp_path / "audit_family")
    run_campaign(family, tmp_path / "audited", ScriptedProposer([P1]), iterations=1)
    run_random_arm(open_campaign(tmp_path / "audited"), LocalExecutor(1), count=2, out=tmp_path / "arm")

    written = {
        name: read_json(tmp_path / name / "campaign.json")
        for name in ("single", "group/repeat-00", "group/repeat-01", "audited", "arm")
    }
    for name, data in written.items():
        assert KEYS <= set(data) <= KEYS | {"group"}, name
        assert not data["family"].startswith("/"), (name, data["family"])
        assert CampaignMeta.from_json(data).to_json() == data, name
    assert written["group/repeat-01"]["group"] == {"dir": "group", "repeat": 1}
    # each repeat's own process is started with its absolute directory; its session records it portably
    assert written["group/repeat-01"]["sessions"][-1]["argv"][:3] == [
        "--resume",
        "--campaign",
        "group/repeat-01",
    ]
    assert written["arm"]["settings"]["budget_from"] == "audited"
    assert written["arm"]["settings"]["space"] == "random-range" and len(written["arm"]["sessions"]) == 1


def test_resume_adds_a_session_and_keeps_the_rest(tmp_path):
    toy = copy_toy(tmp_path)
    campaign = tmp_path / "c"
    assert (
        main(
            [
                "loop",
                "--family",
                str(toy),
                "--proposer",
                "random",
                "--max-iters",
                "1",
                "--campaign",
                str(campaign),
            ]
        )
        == 0
    )
    first = CampaignMeta.read(campaign)
    assert main(["loop", "--resume", "--campaign", str(campaign), "--max-iters", "2"]) == 0
    second = CampaignMeta.read(campaign)
    assert second.sessions[:1] == first.sessions and len(second.sessions) == 2
    assert (second.created, second.family, second.proposer) == (first.created, first.family, first.proposer)
    assert second.settings == {**first.settings, "max_iters": 2}


def test_a_random_arm_of_an_older_writer_reads_with_its_space_in_settings(tmp_path):
    legacy = {
        "family": "f",
        "family_name": "toy",
        "proposer": "random",
        "settings": {"seed": 0},
        "space": "bounds",
    }
    meta = CampaignMeta.from_json(legacy)
    assert meta.settings == {"seed": 0, "space": "bounds"} and "space" not in meta.to_json()


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ([], "does not hold a JSON object"),
        ({"family": "f", "proposer": "tpe"}, "lacks family_name, settings"),
    ],
)
def test_a_malformed_campaign_json_names_what_is_wrong(tmp_path, data, message, capsys):
    (tmp_path / "campaign.json").write_text(json.dumps(data))
    with pytest.raises(CampaignError, match=message):
        CampaignMeta.read(tmp_path)
    (tmp_path / "proposals.jsonl").write_text("")
    main(["check", "--campaign", str(tmp_path)])
    assert "campaign.json" in capsys.readouterr().out


def grow(family_dir, name="WARMUP", axis="optimizer", spec_change=None, choices=None):
    """The toy family with one new parameter (its default in train.py and the baseline), with an
    existing parameter's bounds changed, or with ACTIVATION's ``choices``."""
    registry = json.loads((family_dir / "family.json").read_text())
    if spec_change:
        registry["search_space"]["EPOCHS"]["high"] = spec_change
    elif choices:
        registry["search_space"]["ACTIVATION"]["choices"] = choices
    else:
        registry["axes"].append("algorithm")
        registry["search_space"][name] = {"type": "int", "low": 0, "high": 3, "axis": "algorithm"}
        registry["baseline"]["config"][name] = 0
        registry["protocols"] = {"before": {"exclude_axes": ["algorithm"]}}
        source = (family_dir / "train.py").read_text()
        source = source.replace("EPOCHS = 10", f"EPOCHS = 10\n{name} = 0  # a lever the family gained", 1)
        (family_dir / "train.py").write_text(source)
    (family_dir / "family.json").write_text(json.dumps(registry, indent=2))


def test_a_family_that_only_grew_is_the_same_family_to_its_campaigns(tmp_path, monkeypatch):
    """New parameters (held at their baseline by every earlier run), a choice added to a categorical,
    a range widened and new fields keep a campaign readable and auditable; a narrowed bound of a
    parameter it searched, or a choice taken away, does not."""
    monkeypatch.chdir(tmp_path)
    toy = copy_toy(tmp_path)
    assert (
        main(["loop", "--family", str(toy), "--proposer", "random", "--max-iters", "2", "--campaign", "c"])
        == 0
    )
    grow(toy)
    meta = CampaignMeta.read(tmp_path / "c")
    family = meta.open_family(tmp_path / "c")
    assert "WARMUP" in family.space.names
    assert family.completed({"EPOCHS": 3})["WARMUP"] == 0
    assert main(["check", "--campaign", "c"]) == 0
    grow(toy, choices=["tanh", "silu", "relu", "gelu"])  # one more activation to draw
    assert meta.open_family(tmp_path / "c").space.params["ACTIVATION"].choices == (
        "tanh",
        "silu",
        "relu",
        "gelu",
    )
    grow(toy, spec_change=120)  # EPOCHS up to 120: every earlier run (at most 60) still lies inside
    assert meta.open_family(tmp_path / "c").space.params["EPOCHS"].high == 120
    grow(toy, choices=["tanh", "silu", "relu", "gelu"])  # spec_change left EPOCHS at 120: put it back
    grow(toy, spec_change=60)
    for changed in ({"choices": ["tanh", "relu"]}, {"spec_change": 59}):
        grow(toy, **changed)
        with pytest.raises(CampaignError, match="search space changed"):
            meta.open_family(tmp_path / "c")
        grow(toy, choices=["tanh", "relu", "gelu"])


def test_a_protocol_campaign_opens_after_a_choice_it_never_saw_was_added(tmp_path, monkeypatch):
    """A protocol shows its campaign an axis narrowed to the baseline (FORM: ["plain"]), so the
    registry it saw does not say which of the family's choices came later: the family that grew a
    choice still opens the campaign, the family that lost one does not."""
    monkeypatch.chdir(tmp_path)
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry["axes"].append("algorithm")
    registry["search_space"]["FORM"] = {
        "type": "categorical",
        "choices": ["plain", "fancy"],
        "axis": "algorithm",
    }
    registry["baseline"]["config"]["FORM"] = "plain"
    registry["protocols"] = {"before": {"exclude_axes": ["algorithm"]}}
    (toy / "family.json").write_text(json.dumps(registry, indent=2))
    source = (toy / "train.py").read_text()
    (toy / "train.py").write_text(source.replace("EPOCHS = 10", 'EPOCHS = 10\nFORM = "plain"  # a lever', 1))
    loop = ["loop", "--family", str(toy), "--protocol", "before", "--proposer", "random", "--max-iters", "2"]
    assert main([*loop, "--campaign", "c"]) == 0
    meta = CampaignMeta.read(tmp_path / "c")
    assert json.loads((tmp_path / "c" / "family.json").read_text())["search_space"]["FORM"]["choices"] == [
        "plain"
    ]
    for choices, opens in ((["plain", "fancy", "fancier"], True), (["plain"], False)):
        registry["search_space"]["FORM"]["choices"] = choices
        (toy / "family.json").write_text(json.dumps(registry, indent=2))
        if opens:
            assert meta.open_family(tmp_path / "c").name == meta.family_name
        else:
            with pytest.raises(CampaignError, match="search space changed"):
                meta.open_family(tmp_path / "c")


def test_a_protocol_declared_since_keeps_a_campaign_but_a_changed_one_does_not(tmp_path, monkeypatch):
    """A campaign shown the family's protocols still opens once another protocol is declared (no
    earlier campaign searched it); one whose own protocol changed since does not."""
    monkeypatch.chdir(tmp_path)
    toy = copy_toy(tmp_path)
    registry = json.loads((toy / "family.json").read_text())
    registry["protocols"] = {"short": {"bounds": {"EPOCHS": {"high": 20}}}}
    (toy / "family.json").write_text(json.dumps(registry, indent=2))
    loop = ["loop", "--family", str(toy), "--protocol", "short", "--proposer", "random", "--max-iters", "2"]
    assert main([*loop, "--campaign", "c"]) == 0
    meta = CampaignMeta.read(tmp_path / "c")
    registry["protocols"]["capped"] = {"limits": {"loss": 1.0}}
    (toy / "family.json").write_text(json.dumps(registry, indent=2))
    assert meta.open_family(tmp_path / "c").limits == {}
    registry["protocols"]["short"]["limits"] = {"loss": 1.0}
    (toy / "family.json").write_text(json.dumps(registry, indent=2))
    with pytest.raises(CampaignError, match="changed"):
        meta.open_family(tmp_path / "c")


def test_a_baseline_measured_again_is_the_same_family_but_a_changed_target_is_not(tmp_path, monkeypatch):
    """The baseline's metric is a measurement (the search split moving from 128 to 512 starts
    re-measured both shipped families'): re-measured, the family still opens its campaigns; with
    its target changed, it does not."""
    monkeypatch.chdir(tmp_path)
    toy = copy_toy(tmp_path)
    assert (
        main(["loop", "--family", str(toy), "--proposer", "random", "--max-iters", "2", "--campaign", "c"])
        == 0
    )
    registry = json.loads((toy / "family.json").read_text())
    registry["baseline"]["metric"] = 0.123
    (toy / "family.json").write_text(json.dumps(registry, indent=2))
    meta = CampaignMeta.read(tmp_path / "c")
    assert meta.open_family(tmp_path / "c").registry["baseline"]["metric"] == 0.123
    assert main(["check", "--campaign", "c"]) == 0
    registry["target"] = 2 * registry["target"] + 1
    (toy / "family.json").write_text(json.dumps(registry, indent=2))
    with pytest.raises(CampaignError, match="its metric, target, baseline or search space changed"):
        meta.open_family(tmp_path / "c")
