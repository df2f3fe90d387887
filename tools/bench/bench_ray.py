#!/usr/bin/env python
"""Benchmark: ``collect --ray`` against ``collect --workers`` on one machine, equal worker counts.

For each worker count (``--workers-list``, default 1 and 2), interleaved in rounds, each timed
as a whole command (start-up, Ray's start included, planning, physics, writing):

- ``embodied-envs collect --num NUM --only-success --workers N`` (processes on this machine);
- ``embodied-envs collect --num NUM --only-success --workers N --ray`` (a Ray of this machine
  started for the command with N CPUs, one task per seed).

Prints successful demonstrations per minute of each and their ratio, the median over rounds
(the target: Ray's overhead <= 10%, a ratio >= 0.9), and the same from the collection's own
``wall_time_s`` (without the process's start-up and Ray's). The commands run in a temporary
folder and import the installed package: ``PYTHONPATH=$PWD`` measures this checkout's.

Usage: python tools/bench/bench_ray.py [--num 20] [--rounds 2] [--workers-list 1 2]
       [--layout FILE] [--control-mode pd_joint_delta_pos]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

from embodied_envs.paths import default_layout  # noqa: E402

TARGET = 0.9  # Ray's demos per minute against the local workers' (overhead <= 10%)


def run(num: int, layout: Path, workers: int, mode: str, ray: bool) -> tuple[float, float]:
    """Demonstrations per minute: of the whole command, and of its collection alone."""
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "embodied_envs.cli.main", "collect", "--layout",
               str(layout), "--num", str(num), "--seed", "0", "--only-success", "--workers",
               str(workers), "--control-mode", mode, "--out", tmp]  # fmt: skip
        t = time.perf_counter()
        subprocess.run(cmd + (["--ray"] if ray else []), cwd=tmp, check=True, capture_output=True)
        minutes = (time.perf_counter() - t) / 60
        summary = json.loads((Path(tmp) / layout.stem / "summary.json").read_text())
        return num / minutes, num / (summary["wall_time_s"] / 60)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--num", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--workers-list", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--layout", type=Path, default=default_layout())
    ap.add_argument("--control-mode", default="pd_joint_delta_pos")
    args = ap.parse_args()
    for workers in args.workers_list:
        rows = []
        for _ in range(args.rounds):  # alternate: the machine drifts
            local = run(args.num, args.layout, workers, args.control_mode, ray=False)
            ray = run(args.num, args.layout, workers, args.control_mode, ray=True)
            rows.append((local, ray))
            print(f"  workers {workers}: local {local[0]:.1f} demos/min ({local[1]:.1f} "
                  f"collecting), ray {ray[0]:.1f} ({ray[1]:.1f})", flush=True)  # fmt: skip
        whole = statistics.median(r[0] / lo[0] for lo, r in rows)
        inner = statistics.median(r[1] / lo[1] for lo, r in rows)
        print(f"workers {workers}: ray / local demos per minute, median of {args.rounds}: "
              f"{whole:.2f} whole command, {inner:.2f} collecting "
              f"(target >= {TARGET})")  # fmt: skip


if __name__ == "__main__":
    main()
