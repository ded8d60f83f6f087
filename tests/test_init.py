"""Issue 25: `autoresearch init` writes a working family from a template, `autoresearch check
--family` names each problem of a family in one line, and both work from the wheel, outside the
repository."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest
from test_install import python

from autoresearch.cli import main
from autoresearch.family import Family
from autoresearch.journal import read_jsonl
from autoresearch.templates import MINIMAL_TEMPLATE

ROOT = Path(__file__).resolve().parents[1]
FAMILY_FILES = {"program.md", "program_blind.md", "train.py", "family.json", "prepare.py"}


def test_init_minimal_then_check_and_loop(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "fam"]) == 0
    out = capsys.readouterr().out
    assert "wrote family 'fam' (minimal template, 7 parameters) in fam" in out
    assert "autoresearch loop --family fam --proposer random --max-runs 3" in out
    assert {p.name for p in (tmp_path / "fam").iterdir()} == FAMILY_FILES
    registry = json.loads((tmp_path / "fam" / "family.json").read_text())
    template = json.loads((MINIMAL_TEMPLATE / "family.json").read_text())
    assert registry == {**template, "name": "fam", "best": None}
    assert (tmp_path / "fam" / "train.py").read_bytes() == (MINIMAL_TEMPLATE / "train.py").read_bytes()

    assert main(["check", "--family", "fam"]) == 0
    assert capsys.readouterr().out == "fam: clean\n"
    argv = ["loop", "--family", "fam", "--proposer", "random", "--max-runs", "3", "--campaign", "c"]
    assert main(argv) == 0
    ran = [r for r in read_jsonl(tmp_path / "c" / "proposals.jsonl") if r["status"] == "ran"]
    assert len(ran) == 3 and ran[0]["proposer"] == "baseline"
    assert not list((tmp_path / "fam").glob("runs.jsonl*"))  # runs log beside the campaign, not here


def test_init_names_the_family_and_strips_what_was_measured_for_the_template(tmp_path, capsys):
    target = tmp_path / "deep" / "dock"
    assert main(["init", str(target), "--template", "docking", "--name", "my-dock"]) == 0
    family_dir = ROOT / "families" / "docking"
    shipped = {p.name for p in target.iterdir()}
    assert FAMILY_FILES <= shipped and {"export.py", "report.py"} <= shipped
    assert "ledger.json" not in shipped  # the template's measurements belong to its own campaigns
    for name in shipped - {"family.json"}:
        assert (target / name).read_bytes() == (family_dir / name).read_bytes(), name
    registry = json.loads((target / "family.json").read_text())
    assert (registry["name"], registry["best"], "seed_noise" in registry) == ("my-dock", None, False)
    assert Family.load(target).seed_noise is None
    original = Family.load(family_dir)
    assert original.best is not None and original.seed_noise is not None  # so stripping them is what is seen
    assert registry["search_space"] == original.registry["search_space"]
    assert Family.load(target).name == "my-dock"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["init", "{d}/full"], "exists and is not an empty directory"),
        (
            ["init", "{d}/x", "--template", "nope"],
            "no template 'nope'; installed: docking, minimal, rendezvous",
        ),
        (["init", "{d}/bad name"], "'bad name' is not a plain family name"),
        (["init", "{d}/x", "--name", "../up"], "'../up' is not a plain family name"),
    ],
)
def test_init_refuses_and_writes_nothing(tmp_path, capsys, argv, message):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert main([a.format(d=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("autoresearch init: error: ") and message in err and err.count("\n") == 1
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_init_fills_an_empty_directory(tmp_path):
    (tmp_path / "empty").mkdir()
    assert main(["init", str(tmp_path / "empty")]) == 0
    assert {p.name for p in (tmp_path / "empty").iterdir()} == FAMILY_FILES
    assert [p.name for p in tmp_path.iterdir()] == ["empty"]  # no staging directory left beside it


def test_check_family_names_each_problem_in_one_line(tmp_path, capsys):
    assert main(["init", str(tmp_path / "fam")]) == 0
    capsys.readouterr()
    fam = tmp_path / "fam"
    registry = json.loads((fam / "family.json").read_text())
    registry["direction"] = "up"
    registry["target"] = "low"
    (fam / "family.json").write_text(json.dumps(registry))
    source = (fam / "train.py").read_text()
    (fam / "train.py").write_text(source.replace("DROPOUT = 0.0  #", "DROPOUT = 0.9  #", 1))
    (fam / "prepare.py").write_text("import sys\nsys.exit('check failed: the data set is missing')\n")

    assert main(["check", "--family", str(fam)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"{fam}: 4 problem(s)"
    assert lines[1] == f"  {fam / 'family.json'}: 'direction' must be 'maximize' or 'minimize', got 'up'"
    assert lines[2] == f"  {fam / 'family.json'}: 'target' must be a finite number or null"
    assert lines[3].startswith(f"  {fam / 'train.py'}: an editable default is outside the search space:")
    assert "DROPOUT" in lines[3]
    assert lines[4] == "  prepare.py --check failed (exit 1): check failed: the data set is missing"
    with pytest.raises(Exception, match="'direction' must be"):  # the loop refuses the same family
        Family.load(fam)


def test_check_family_errors(tmp_path, capsys):
    assert main(["check", "--family", str(tmp_path / "nowhere")]) == 2
    assert "is not a directory, and no families/nowhere exists" in capsys.readouterr().err
    (tmp_path / "half").mkdir()
    assert main(["check", "--family", str(tmp_path / "half")]) == 1
    out = capsys.readouterr().out
    assert "missing program.md, program_blind.md, train.py, family.json, prepare.py" in out


def test_init_research_template_without_torch_names_the_extra(tmp_path):
    """init needs no torch; the family's prepare check names the extra its training needs."""
    code = (
        "import sys; from autoresearch.cli import main\n"
        f"assert main(['init', {str(tmp_path / 'r')!r}, '--template', 'rendezvous']) == 0\n"
        f"sys.exit(main(['check', '--family', {str(tmp_path / 'r')!r}]))\n"
    )
    done = python(code, block=("torch",), tmp_path=tmp_path)
    assert done.returncode == 1, done.stderr
    assert "pip install 'cwh-autoresearch[families]'" in done.stdout
    assert done.stdout.count("problem") == 1 and "1 problem(s)" in done.stdout


@pytest.mark.slow
def test_wheel_init_loop_audit_outside_the_repository(tmp_path):
    """The wheel carries every template; installed in a fresh venv and run in a directory outside the
    repository, init -> check -> loop -> audit work. The venv gets the wheel alone; its
    dependencies come from this environment's site-packages through a .pth line, which adds that
    directory but processes none of its .pth files, so this repository's editable install stays off."""
    dist = tmp_path / "dist"
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", dist, ROOT],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = dist.glob("cwh_autoresearch-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for template, package in (
        ("docking", "cwh_envs"),
        ("rendezvous", "cwh_envs"),
        ("minimal", "autoresearch"),
    ):
        for name in FAMILY_FILES:
            assert f"{package}/templates/{template}/{name}" in names, (template, name)
    assert not [n for n in names if "runs.jsonl" in n or n.endswith(".pyc")]

    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", py, "install", "-q", "--no-deps", "--no-index", wheel],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert installed.returncode == 0, installed.stderr[-2000:]
    site = subprocess.run(
        [py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    Path(site, "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")

    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{env_dir / 'bin'}{os.pathsep}{env['PATH']}"

    def sh(*argv: str) -> str:
        done = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, (argv, done.stdout[-2000:], done.stderr[-2000:])
        return done.stdout

    where = sh(
        "python", "-c", "import autoresearch, cwh_envs; print(autoresearch.__file__, cwh_envs.__file__)"
    )
    assert str(ROOT) not in where and where.count(str(site)) == 2
    sh("autoresearch", "init", "fam")
    assert sh("autoresearch", "check", "--family", "fam") == "fam: clean\n"
    sh(
        "autoresearch",
        "loop",
        "--family",
        "fam",
        "--proposer",
        "random",
        "--max-runs",
        "3",
        "--campaign",
        "c",
    )
    sh("autoresearch", "audit", "--campaign", "c", "--noise-seeds", "3", "--seeds", "3", "--count", "3")
    assert (work / "c" / "report.md").is_file()
    assert json.loads((work / "fam" / "ledger.json").read_text())["seed_noise"]["k"] == 3
    sh("autoresearch", "init", "dock", "--template", "docking")
    assert (work / "dock" / "train.py").read_bytes() == (
        ROOT / "families" / "docking" / "train.py"
    ).read_bytes()
