#!/usr/bin/env python
"""Benchmark: start-up of the command line (wall time of whole processes, median of N runs).

Times ``embodied-envs --help``, ``embodied-envs layout validate`` on each shipped layout and
``python -c "import embodied_envs"``, next to two baselines measured in the same run: a bare
``python -c pass`` and ``python -c "import torch"`` (what every command paid before the
simulator was imported lazily).

Usage: python tools/bench/bench_cli.py [--runs 7]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def wall(cmd: list[str], runs: int) -> float:
    """Median wall seconds of ``cmd`` (one warm-up run first, for the file cache)."""
    env = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
    times = []
    for i in range(runs + 1):
        start = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT, env=env)
        if i:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    py = sys.executable
    cli = [py, "-m", "embodied_envs.cli.main"]
    rows = [
        ("python -c pass (baseline)", [py, "-c", "pass"]),
        ("python -c 'import torch' (baseline)", [py, "-c", "import torch"]),
        ("python -c 'import embodied_envs'", [py, "-c", "import embodied_envs"]),
        ("embodied-envs --help", [*cli, "--help"]),
    ]
    rows += [
        (f"embodied-envs layout validate {p.name}", [*cli, "layout", "validate", str(p)])
        for p in sorted((ROOT / "layouts").glob("*.json"))
    ]
    torch_s = None
    for label, cmd in rows:
        s = wall(cmd, args.runs)
        torch_s = s if "import torch" in label else torch_s
        ratio = f", {s / torch_s:.2f} x import torch" if torch_s and "baseline" not in label else ""
        print(f"{label:45s} {s:6.2f} s{ratio}")


if __name__ == "__main__":
    main()
