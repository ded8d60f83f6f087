"""What each install costs on disk, and how fast the two halves start.

    .venv/bin/python benchmarks/bench_install.py [--dir /tmp/cwh-installs] [--repeats 20]

Builds one virtual environment per install under ``--dir`` (kept and reused: delete it to rebuild),
each from this checkout (``pip install -e .[EXTRAS]``, torch first from TORCH_SPEC as
scripts/bootstrap.sh does), and reports the size of its site-packages. Then, in the base install,
the median wall time of whole processes (``--repeats`` each, interleaved so that drift hits all
alike): ``python -c pass`` (the interpreter alone), ``import gymnasium``, ``import cwh_envs``
(registers the envs) and ``autoresearch --help``. The targets (issue 25): ``autoresearch --help``
within 0.3 s, ``import cwh_envs`` within 0.15 s of ``import gymnasium``. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
INSTALLS = {  # name -> extras
    "base": "",
    "base + [llm]": "llm",
    "base + [families] (torch)": "families",
    "[all]": "all",
}
TORCH_SPEC = os.environ.get("TORCH_SPEC", "torch==2.13.0")


def venv_of(where: Path, name: str, extras: str) -> Path:
    """The environment of one install, built once."""
    venv = where / (extras or "base")
    python = venv / "bin" / "python"
    if not python.exists():
        print(f"[bench_install] building {name} in {venv}", file=sys.stderr, flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        pip = [str(python), "-m", "pip", "install", "-q"]
        if extras in ("families", "all"):
            subprocess.run([*pip, TORCH_SPEC], check=True)
        subprocess.run([*pip, "-e", f"{ROOT}[{extras}]" if extras else str(ROOT)], check=True)
    return venv


def site_packages_mb(venv: Path) -> float:
    (site,) = venv.glob("lib/python*/site-packages")
    total = sum(f.stat().st_size for f in site.rglob("*") if f.is_file() and not f.is_symlink())
    return total / 2**20


def wall_times(commands: dict[str, list[str]], repeats: int) -> dict[str, float]:
    """Median wall seconds of each command as a whole process, runs interleaved."""
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(repeats):
        for name, command in commands.items():
            started = time.perf_counter()
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
            times[name].append(time.perf_counter() - started)
    return {name: statistics.median(t) for name, t in times.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=Path("/tmp/cwh-installs"))
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    venvs = {name: venv_of(args.dir, name, extras) for name, extras in INSTALLS.items()}
    base = venvs["base"] / "bin"
    python = str(base / "python")
    starts = wall_times(
        {
            "python -c pass": [python, "-c", "pass"],
            "import gymnasium": [python, "-c", "import gymnasium"],
            "import cwh_envs": [python, "-c", "import cwh_envs"],
            "autoresearch --help": [str(base / "autoresearch"), "--help"],
        },
        args.repeats,
    )
    print(
        f"Python {platform.python_version()}, {os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.2f}); "
        f"site-packages of a fresh venv per install; start-up: median of {args.repeats} whole processes "
        "in the base install\n"
    )
    print("| measure | value | comparison |")
    print("|---|---:|---|")
    size = {name: site_packages_mb(venv) for name, venv in venvs.items()}
    for name, mb in size.items():
        print(f"| install size, {name} | {mb:,.0f} MB | {mb / size['base']:.1f}x base |")
    gym, envs, cli = starts["import gymnasium"], starts["import cwh_envs"], starts["autoresearch --help"]
    print(f"| start-up, python -c pass | {starts['python -c pass']:.3f} s | the interpreter alone |")
    print(f"| start-up, import gymnasium | {gym:.3f} s | |")
    print(
        f"| start-up, import cwh_envs | {envs:.3f} s | +{envs - gym:.3f} s over gymnasium (target <= 0.15 s) |"
    )
    print(f"| start-up, autoresearch --help | {cli:.3f} s | target <= 0.3 s |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
