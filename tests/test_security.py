"""Hostile proposals are refused with a reason, recorded as invalid, and never executed."""

from loop_helpers import ScriptedProposer, copy_toy, run_loop, snapshot

from autoresearch.proposers.base import Proposal


def hostile(sentinel):
    cmd = f"touch {sentinel}"
    return [
        {"LEARNING_RATE": f"__import__('os').system('{cmd}')"},
        {"ACTIVATION": f"tanh\"\nimport os; os.system('{cmd}')\n#"},
        {"ACTIVATION": f"'; import os; os.system(\"{cmd}\"); '"},
        {"EPOCHS": "1 # comment"},
        {"EPOCHS": "0; import os"},
        {"DROPOUT": {"__class__": "os.system"}},
        {"DROPOUT": [0.1]},
        {f"__import__('os').system('{cmd}')": 1},
        {"EPOCHS": 10**6},
        {"LEARNING_RATE": float("nan")},
        {"LEARNING_RATE": float("inf")},
        {"MOMENTUM": float("-inf")},
        {"EPOCHS": True},
        {"EPOCHS": "3"},
        {"EPOCHS": 3.5},
        {"USE_NORM": 1},
        Proposal(kind="propose", overrides=f"EPOCHS = __import__('os').system('{cmd}')"),
        Proposal(kind="propose", overrides={"EPOCHS": object()}),
    ]


def test_hostile_proposals_are_refused_recorded_and_never_run(tmp_path):
    toy = copy_toy(tmp_path)
    before = snapshot(toy)
    sentinel = tmp_path / "SENTINEL"
    attacks = hostile(sentinel)
    proposer = ScriptedProposer([*attacks, {"EPOCHS": 12}])
    _, records = run_loop(toy, proposer, tmp_path / "c", max_iters=len(attacks) + 2, max_failures=100)
    refused = records[1 : 1 + len(attacks)]
    assert all(r["status"] == "invalid" and r["reason"] and r["run_id"] is None for r in refused)
    reasons = [r["reason"] for r in refused]
    assert "LEARNING_RATE: expected a number, got str" in reasons[0]
    assert "ACTIVATION:" in reasons[1] and "is not one of" in reasons[1]
    assert "unknown key(s)" in reasons[7]
    assert "outside [0, 60]" in reasons[8] and "not finite" in reasons[9]
    assert "must be an object" in reasons[16] and "expected an integer, got object" in reasons[17]
    assert records[-2]["status"] == "ran" and records[-1]["trigger"] == "max_iters"  # the loop carried on
    # Only the baseline and the one legitimate proposal were ever written as a script and run.
    assert sorted(p.name for p in (tmp_path / "c" / "runs").iterdir()) == [
        "it0001",
        f"it{len(attacks) + 2:04d}",
    ]
    assert not sentinel.exists()
    assert snapshot(toy) == before
    # The raw hostile text is kept as data in the trail, for the audit.
    assert refused[0]["proposal"]["overrides"] == attacks[0]
    assert refused[17]["proposal"]["overrides"].startswith("{'EPOCHS': <object object")
