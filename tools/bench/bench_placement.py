#!/usr/bin/env python
"""Benchmark: placed layouts per second (one core) and constraint violations over 1,000 seeds.

Violations are counted with the independent shapely checker of the test suite.

Usage: python tools/bench/bench_placement.py [--seeds 1000]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "layout"))

from embodied_envs.layout import LayoutInfo, load_layout  # noqa: E402
from embodied_envs.layout.placement import place  # noqa: E402
from embodied_envs.paths import shipped_layouts  # noqa: E402


def with_extra_object(layout: LayoutInfo, node: str = "banana") -> LayoutInfo:
    """The layout with one more distractor on the table (the shipped banana asset)."""
    data = layout.to_dict()
    data["tree"][layout.context].append([node, "ON"])
    data["relation"]["distractor_objs"].append(node)
    data["objs_mapping"][node] = "distractor_objs"
    data["assets"][node] = "../assets/banana"
    data["position"][node] = [0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 1.0]
    return LayoutInfo.from_dict(data, source=layout.source)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seeds", type=int, default=1000)
    args = ap.parse_args()
    from test_placement import check_constraints

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core, as the target says
    cases = [(path.name, load_layout(path)) for path in shipped_layouts()]
    cases.append(("default.json+banana", with_extra_object(load_layout(shipped_layouts()[0]))))
    for name, layout in cases:
        place(layout, 0)  # warm the geometry caches
        t = time.perf_counter()
        placed = [place(layout, s) for s in range(args.seeds)]
        rate = args.seeds / (time.perf_counter() - t)
        violations = sum(bool(check_constraints(p)) for p in placed)
        n_obj = len(layout.object_nodes()) - 1
        print(
            f"{name:20s} {n_obj} objects: {rate:7.1f} layouts/s, "
            f"{violations} of {args.seeds} seeds violate a constraint"
        )


if __name__ == "__main__":
    main()
