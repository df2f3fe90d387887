#!/usr/bin/env python
"""Benchmark: how many expert demonstrations convert to each controller.

For each dataset (a ``trajectory.h5`` that ``embodied-envs collect`` wrote, in ``pd_joint_pos``)
and each target mode, runs both converters on every episode and counts the episodes whose
converted replay ends in success (what each tool saves):

- ManiSkill's ``python -m mani_skill.trajectory.replay_trajectory --traj-path X -c MODE``;
- ``embodied-envs replay --traj-path X -c MODE``.

Prints a table of kept/total per dataset, mode and converter.

Usage: python tools/bench/bench_convert.py TRAJ.h5 [TRAJ.h5 ...] [--modes pd_joint_delta_pos ...]
       [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

MODES = ("pd_joint_delta_pos", "pd_joint_vel", "pd_ee_delta_pos", "pd_ee_delta_pose")
CONVERTERS = {
    "maniskill": [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory"],
    "embodied-envs": [sys.executable, "-m", "embodied_envs.cli.main", "replay"],
}
SAVED = re.compile(r"(\d+)/(\d+)=[\d.]+% demos saved")


def kept(converter: str, traj: Path, mode: str) -> tuple[int, int]:
    """(kept, total) episodes of ``traj`` converted to ``mode`` by ``converter``."""
    cmd = [*CONVERTERS[converter], "--traj-path", str(traj), "-c", mode]
    run = subprocess.run(cmd, capture_output=True, text=True, env=os.environ)
    found = SAVED.findall(run.stdout + run.stderr)
    if run.returncode or not found:
        tail = (run.stdout + run.stderr)[-2000:]
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {run.returncode}):\n{tail}")
    result = int(found[-1][0]), int(found[-1][1])
    print(f"{converter} {traj} {mode}: {result[0]}/{result[1]}", file=sys.stderr, flush=True)
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("traj", nargs="+", type=Path, help="trajectory.h5 files (pd_joint_pos)")
    ap.add_argument("--modes", nargs="+", default=list(MODES))
    ap.add_argument("--converters", nargs="+", default=list(CONVERTERS), choices=CONVERTERS)
    ap.add_argument("--jobs", type=int, default=2, help="conversions run at once")
    args = ap.parse_args()
    jobs = [(c, t, m) for t in args.traj for m in args.modes for c in args.converters]
    with ThreadPoolExecutor(args.jobs) as pool:
        results = dict(zip(jobs, pool.map(lambda j: kept(*j), jobs), strict=True))
    print("| dataset | mode | " + " | ".join(args.converters) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in args.converters) + " |")
    for t in args.traj:
        for m in args.modes:
            cells = [f"{k}/{n}" for k, n in (results[c, t, m] for c in args.converters)]
            print(f"| {t.parent.name} | `{m}` | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
