"""The shipped evaluation splits (cwh_envs.splits): fixed, versioned, verified, and the same starts a
screen from scratch draws; and a cache that was tampered with is rebuilt or refused, never used."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from cwh_envs import datasets, splits
from cwh_envs.datasets import CacheMiss, evaluation_set, screen_split
from cwh_envs.problems import DockingProblem, RendezvousProblem
from cwh_envs.rollout import control_effort

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import make_splits  # noqa: E402  (scripts/ is not a package)

# Every shipped (name, version) and its identity. A changed file under an unchanged version fails
# here: make a new version (scripts/make_splits.py does) and add its line; never edit a line.
SHIPPED = {
    ("rendezvous/search", 0): "95d632a3297decbc",
    ("rendezvous/test", 0): "ab36e851ff2e11f7",
    ("docking/search", 0): "2531516038398d8b",
    ("docking/test", 0): "992af5aaaa354400",
    ("docking-constrained/search", 0): "851dfe1a4c614ba7",
    ("docking-constrained/test", 0): "e0d45611f81d3533",
}


@pytest.fixture
def fresh_manifest(monkeypatch):
    """Forget what this process read from cwh_envs/data (the tests below point it elsewhere)."""
    for cached in (splits.manifest, splits._load):
        cached.cache_clear()
    yield monkeypatch
    for cached in (splits.manifest, splits._load):
        cached.cache_clear()


def data_copy(tmp_path: Path, monkeypatch) -> Path:
    copy = tmp_path / "data"
    shutil.copytree(splits.DATA_DIR, copy)
    monkeypatch.setattr(splits, "DATA_DIR", copy)
    monkeypatch.setattr(splits, "MANIFEST", copy / "manifest.json")
    return copy


def test_every_shipped_file_matches_the_manifest_and_its_version():
    entries = splits.manifest()["splits"]
    assert {(e["name"], e["version"]): e["identity"] for e in entries} == SHIPPED
    for entry in entries:
        path = splits.DATA_DIR / entry["file"]
        assert hashlib.sha256(path.read_bytes()).hexdigest() == entry["sha256"], entry["name"]
        shipped = splits._load(entry["name"], entry["version"])
        assert len(shipped) == entry["n"] and shipped.starts.shape == (entry["n"], 6)
        assert np.all(shipped.energy > 0)
        assert splits.split_identity(shipped.starts, shipped.goals) == entry["identity"]
    assert sum(path.stat().st_size for path in splits.DATA_DIR.iterdir()) < 600_000  # a few hundred KB


def test_a_split_changed_under_the_same_version_fails_the_version_table(tmp_path, fresh_manifest):
    data_copy(tmp_path, fresh_manifest)
    raw = np.load(splits.DATA_DIR / "rendezvous-search-v0.npz")
    starts = raw["starts"].copy()
    starts[7, 0] += 1e-9  # one coordinate of one start, a nanometre
    entry = make_splits.write_split("rendezvous/search", starts, raw["goals"], raw["energy"])
    # The script never overwrites a shipped split: the changed starts are version 1 of the name ...
    assert entry["version"] == 1 and (splits.DATA_DIR / "rendezvous-search-v0.npz").exists()
    table = {
        (e["name"], e["version"]): e["identity"] for e in json.loads(splits.MANIFEST.read_text())["splits"]
    }
    assert table != SHIPPED  # ... which the table above does not hold: the test above would fail
    again = make_splits.write_split("rendezvous/search", starts, raw["goals"], raw["energy"])
    assert again["version"] == 1  # the same starts again: unchanged, no new version


@pytest.mark.needs("families")
def test_each_family_scores_on_a_shipped_split_and_pins_its_identity():
    from cwh_envs.prepare import split_ids

    for family in ("rendezvous", "docking", "docking-constrained"):
        directory = ROOT / "families" / family
        spec = importlib.util.spec_from_file_location(f"prepare_{family}", directory / "prepare.py")
        sys.path.insert(0, str(directory))
        try:
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        finally:
            sys.path.remove(str(directory))
            sys.modules.pop("train", None)
        needs = module.NEEDS
        registry = json.loads((directory / "family.json").read_text())
        shipped = {
            split: splits.shipped_split(needs.task, needs.problem, split) for split in ("search", "test")
        }
        assert len(shipped["search"]) >= needs.n_eval and len(shipped["test"]) >= needs.n_test
        assert registry["split_ids"] == split_ids(needs), family


@pytest.mark.parametrize(
    "name",
    [
        "rendezvous/search",
        "rendezvous/test",
        "docking/search",
        "docking/test",
        "docking-constrained/search",
        "docking-constrained/test",
    ],
)
def test_a_screen_from_scratch_draws_the_shipped_starts(name):
    """What a second machine would build: the first starts of each split screened here from their
    stream, with the expert's energy from each, against the shipped file."""
    task, problem, split, _ = make_splits.SPLITS[name]
    n = 3 if "constrained" in name else 16  # the constrained expert takes ~2 s a start
    held = screen_split(task, n, problem, split=split, check=False)
    shipped = splits.shipped_split(task, problem, split)
    # Bit for bit on the machine that made them and on numpy's newest release; numpy's lowest declared
    # floor rounds the docking sampler's trigonometry otherwise, by 2.5e-14 m at most (CI's Python 3.10
    # job): the very drift that made the splits ship. Same starts, to rounding.
    np.testing.assert_allclose(held.starts, shipped.starts[:n], rtol=0, atol=1e-9)
    np.testing.assert_allclose(held.goals, shipped.goals[:n], rtol=0, atol=1e-9)
    assert shipped.energy_mismatch(control_effort(held.trajectory_thrust(), problem)[0]) is None


def test_a_shipped_file_that_does_not_match_its_checksum_is_refused(tmp_path, fresh_manifest):
    copy = data_copy(tmp_path, fresh_manifest)
    path = copy / "docking-search-v0.npz"
    payload = bytearray(path.read_bytes())
    payload[-40] ^= 1
    path.write_bytes(bytes(payload))
    with pytest.raises(splits.SplitError, match=r"docking/search-v0: .*docking-search-v0\.npz has sha256"):
        evaluation_set("docking", 4, cache_dir=tmp_path / "cache")


def test_an_expert_that_disagrees_with_the_shipped_energy_names_the_start(tmp_path, fresh_manifest):
    copy = data_copy(tmp_path, fresh_manifest)
    raw = dict(np.load(copy / "rendezvous-test-v0.npz"))
    raw["energy"][5] *= 1.01  # the reference of start 5, one percent off
    entry = next(
        e for e in json.loads(splits.MANIFEST.read_text())["splits"] if e["name"] == "rendezvous/test"
    )
    np.savez_compressed(copy / entry["file"], **raw)
    manifest = json.loads(splits.MANIFEST.read_text())
    for e in manifest["splits"]:
        if e["name"] == "rendezvous/test":
            e["sha256"] = hashlib.sha256((copy / e["file"]).read_bytes()).hexdigest()
    splits.MANIFEST.write_text(json.dumps(manifest))
    with pytest.raises(splits.SplitError, match=r"start 5 of rendezvous/test-v0 .*1 start\(s\) disagree"):
        evaluation_set("rendezvous", 8, split="test", cache_dir=tmp_path / "cache")
    assert evaluation_set("rendezvous", 5, split="test", cache_dir=tmp_path / "cache").n_episodes == 5


def cache_file(cache: Path) -> Path:
    (path,) = cache.glob("evaluation-rendezvous-*.npz")
    return path


def rewrite(path: Path, change, checksum: bool) -> None:
    """The cache file with ``change`` applied to its arrays, its key text left alone, and its stored
    checksum recomputed when ``checksum`` (a tamperer who knows the format)."""
    with np.load(path) as stored:
        arrays = {name: stored[name] for name in stored.files}
    change(arrays)
    fields = {k: v for k, v in arrays.items() if k not in ("key", "checksum")}
    if checksum:
        arrays["checksum"] = np.array(datasets._checksum(fields))
    np.savez(path, **arrays)


@pytest.mark.parametrize("checksum", [False, True], ids=["arrays-changed", "checksum-recomputed"])
def test_a_tampered_cache_is_rebuilt_or_refused_never_used(tmp_path, capsys, checksum):
    cache = tmp_path / "cache"
    honest = evaluation_set("rendezvous", 64, split="test", cache_dir=cache)
    path = cache_file(cache)

    def halve(arrays):  # every start halved: an easier split under the same name
        arrays["starts"] = arrays["starts"] / 2
        arrays["observations"][:, :6] /= 2

    rewrite(path, halve, checksum)
    capsys.readouterr()
    with pytest.raises(CacheMiss, match="checksum" if not checksum else "not those of the shipped split"):
        evaluation_set("rendezvous", 64, split="test", cache_dir=cache, build=False)
    again = evaluation_set("rendezvous", 64, split="test", cache_dir=cache)
    assert f"the cache file {path}" in capsys.readouterr().err
    np.testing.assert_array_equal(again.starts, honest.starts)
    assert again.content_key == honest.content_key
    # rebuilt in place: read back without a word
    evaluation_set("rendezvous", 64, split="test", cache_dir=cache, build=False)
    assert capsys.readouterr().err == ""


def test_a_tampered_expert_in_the_cache_is_caught_by_the_shipped_energy(tmp_path, capsys):
    cache = tmp_path / "cache"
    honest = evaluation_set("rendezvous", 16, split="test", cache_dir=cache)

    def cheaper(arrays):  # the expert's thrust scaled down: every fuel ratio would look worse
        arrays["actions"] = arrays["actions"] * 0.9

    rewrite(cache_file(cache), cheaper, checksum=True)
    again = evaluation_set("rendezvous", 16, split="test", cache_dir=cache)
    assert "start 0 of rendezvous/test-v0" in capsys.readouterr().err
    np.testing.assert_array_equal(again.actions, honest.actions)


def test_training_sets_in_the_cache_are_checked_too(tmp_path, capsys):
    honest = datasets.demonstrations("rendezvous", 4, cache_dir=tmp_path)
    (path,) = tmp_path.glob("demonstrations-*.npz")
    rewrite(path, lambda arrays: arrays.__setitem__("actions", arrays["actions"] * 0), checksum=False)
    again = datasets.demonstrations("rendezvous", 4, cache_dir=tmp_path)
    assert "does not match the checksum" in capsys.readouterr().err
    np.testing.assert_array_equal(again.actions, honest.actions)


def test_a_split_larger_than_the_shipped_one_is_refused():
    with pytest.raises(ValueError, match=r"rendezvous/search-v0 holds 512 starts; n=513"):
        evaluation_set("rendezvous", 513)


def test_a_problem_of_ones_own_is_screened_here_with_a_warning(tmp_path):
    problem = RendezvousProblem(horizon=60)
    assert splits.shipped_split("rendezvous", problem, "search") is None
    with pytest.warns(UserWarning, match="no search split ships for this rendezvous problem"):
        held = evaluation_set("rendezvous", 4, problem=problem, cache_dir=tmp_path)
    assert held.starts.shape == (4, 6)
    assert datasets.shipped_split_label("rendezvous", 4, problem) is None
    assert datasets.shipped_split_label("docking", 128, DockingProblem()) == "docking/search-v0, first 128"


def test_prepare_check_names_a_cache_file_that_fails_its_checks(tmp_path, monkeypatch, capsys):
    from cwh_envs.prepare import DataNeeds, check, warm

    monkeypatch.setenv("CWH_ENVS_CACHE", str(tmp_path))
    needs = DataNeeds(
        "rendezvous", RendezvousProblem(), pool_demos=4, data_seed=0, n_eval=8, obs_dim=7, n_test=8
    )
    assert warm(needs) == 0
    (path,) = [p for p in tmp_path.glob("evaluation-rendezvous-*.npz") if "test" in str(np.load(p)["key"])]
    rewrite(path, lambda arrays: arrays.__setitem__("starts", arrays["starts"] / 2), checksum=False)
    capsys.readouterr()
    assert check(needs) == 1
    err = capsys.readouterr().err
    assert "rendezvous test split" in err and "fails its checks" in err and "checksum" in err
    assert warm(needs) == 0  # --warm-cache builds it again


def test_a_stale_cache_file_is_rebuilt(tmp_path, capsys):
    """A file under the right name whose key is another build's (older code, other constants) is not
    the set asked for: it is built again, with a line that says so."""
    cache = tmp_path / "cache"
    honest = datasets.demonstrations("rendezvous", 4, cache_dir=cache)
    (path,) = cache.glob("demonstrations-*.npz")

    def older(arrays):
        key = json.loads(str(arrays["key"]))
        arrays["key"] = np.array(json.dumps({**key, "code": "an older builder"}, sort_keys=True))

    rewrite(path, older, checksum=True)
    capsys.readouterr()
    with pytest.raises(CacheMiss, match="was written for another set"):
        datasets.demonstrations("rendezvous", 4, cache_dir=cache, build=False)
    again = datasets.demonstrations("rendezvous", 4, cache_dir=cache)
    assert "was written for another set: building it again" in capsys.readouterr().err
    np.testing.assert_array_equal(again.actions, honest.actions)
