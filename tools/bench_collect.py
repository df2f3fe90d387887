#!/usr/bin/env python
"""Benchmark: demonstration collection (``embodied-envs collect``) on this machine.

Collects ``--num`` demonstrations of the default layout with 1 and with 2 worker processes
(observations ``none``, as ManiSkill's demos) and prints demonstrations per minute (wall time of
the whole command: env start-up, solver, writing, merging) and MB per 100 demonstrations.

Usage: python tools/bench_collect.py [--num 12]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

from embodied_envs.paths import default_layout  # noqa: E402
from embodied_envs.pipelines.collect import CollectPlan, collect  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--num", type=int, default=12)
    args = ap.parse_args()
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as tmp:
            plan = CollectPlan(layout=str(default_layout()), num=args.num, workers=workers)
            t = time.perf_counter()
            summary = collect(plan, Path(tmp))
            minutes = (time.perf_counter() - t) / 60
            size = sum(p.stat().st_size for p in (Path(tmp) / "default").iterdir())
        print(
            f"{workers} worker(s): {args.num / minutes:5.1f} demonstrations/min "
            f"({summary.successes}/{summary.attempted} successful), "
            f"{size / 1e6 / args.num * 100:5.1f} MB per 100 demonstrations (obs none)"
        )


if __name__ == "__main__":
    main()
