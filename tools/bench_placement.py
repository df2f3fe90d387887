#!/usr/bin/env python
"""Benchmark: placed layouts per second (one core) and constraint violations over 1,000 seeds.

Violations are counted with the independent shapely checker of the test suite.

Usage: python tools/bench_placement.py [--seeds 1000]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "layout"))

from embodied_envs.layout import load_layout  # noqa: E402
from embodied_envs.layout.placement import place  # noqa: E402
from embodied_envs.paths import shipped_layouts  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seeds", type=int, default=1000)
    args = ap.parse_args()
    from test_placement import check_constraints

    for path in shipped_layouts():
        layout = load_layout(path)
        place(layout, 0)  # warm the geometry caches
        t = time.perf_counter()
        placed = [place(layout, s) for s in range(args.seeds)]
        rate = args.seeds / (time.perf_counter() - t)
        violations = sum(bool(check_constraints(p)) for p in placed)
        n_obj = len(layout.object_nodes()) - 1
        print(
            f"{path.name:18s} {n_obj} objects: {rate:7.1f} layouts/s, "
            f"{violations} of {args.seeds} seeds violate a constraint"
        )


if __name__ == "__main__":
    main()
