#!/usr/bin/env python
"""Benchmark: demonstration collection against ManiSkill's own motion-planning runner.

In one run, interleaved, each timed as a whole command (start-up, planning, physics, writing):

- ManiSkill's ``python -m mani_skill.examples.motionplanning.panda.run -e PickCube-v1
  -n NUM --only-count-success -b cpu`` (one process, observations ``none``);
- ``embodied-envs collect --num NUM --only-success --workers 1 --control-mode MODE`` on each
  layout (observations ``none``, as ManiSkill's demos; MODE by default ``pd_joint_delta_pos``,
  the env's default controller, recorded natively: demos in the controller learners use, with
  no conversion after), and with ``--workers 2`` on the default layout.

Prints successful demonstrations per minute, the ratio to PickCube's runner (the target is
>= 1.0 with one worker on the default layout) and MB per 100 demonstrations. The commands run
in a temporary folder and import the installed package: ``PYTHONPATH=$PWD`` measures this
checkout's; ``OMP_NUM_THREADS=1`` gives both sides one thread.

``--before DIR`` times another checkout's ``collect`` too, in the same pairs (before/after).

Usage: python tools/bench/bench_collect.py [--num 20] [--repeats 1] [--layout FILE ...]
       [--before DIR] [--control-mode pd_joint_delta_pos]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

from embodied_envs.paths import default_layout, shipped_layouts  # noqa: E402


def timed(cmd: list[str], cwd: str, env: dict | None = None) -> float:
    """Minutes the command ran (it must succeed)."""
    t = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, capture_output=True, env=env or os.environ)
    return (time.perf_counter() - t) / 60


def pickcube(num: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        runner = "mani_skill.examples.motionplanning.panda.run"
        cmd = [sys.executable, "-m", runner, "-e", "PickCube-v1", "-n", str(num),
               "--only-count-success", "-b", "cpu", "--record-dir", tmp]  # fmt: skip
        return num / timed(cmd, tmp)


def ours(
    num: int, layout: Path, workers: int, mode: str, checkout: Path | None = None
) -> tuple[float, float]:
    """Demonstrations per minute and MB per 100 demonstrations (``checkout``: the package of
    that folder, on ``PYTHONPATH``; ``pd_joint_pos`` is asked without ``--control-mode``, which
    a checkout from before it lacks)."""
    env = None if checkout is None else {**os.environ, "PYTHONPATH": str(checkout)}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "embodied_envs.cli.main", "collect", "--layout",
               str(layout), "--num", str(num), "--only-success", "--workers", str(workers),
               "--out", "out"]  # fmt: skip
        if mode != "pd_joint_pos":
            cmd += ["--control-mode", mode]
        rate = num / timed(cmd, tmp, env)
        size = sum(p.stat().st_size for p in (Path(tmp) / "out" / layout.stem).iterdir())
    return rate, size / 1e6 / num * 100


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--num", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=1, help="pairs per case (median ratio)")
    ap.add_argument("--layout", type=Path, nargs="+", default=None)
    ap.add_argument("--before", type=Path, default=None, help="another checkout (e.g. `git "
                    "worktree add DIR COMMIT`): its collect too, right after ours in each pair")
    ap.add_argument("--control-mode", default="pd_joint_delta_pos", help="collect's mode")
    args = ap.parse_args()
    runs = [(path.resolve(), 1) for path in args.layout or shipped_layouts()]  # cwd: a temp dir
    runs.append((default_layout(), 2))
    for path, workers in runs:
        pairs = []
        for _ in range(args.repeats):  # each pair back to back: the machine drifts
            base = pickcube(args.num)
            mode = args.control_mode
            before = ours(args.num, path, workers, mode, args.before)[0] if args.before else None
            pairs.append((*ours(args.num, path, workers, mode), base, before))
        rate, mb, base = (statistics.median(x) for x in list(zip(*pairs, strict=True))[:3])
        ratio = statistics.median(r / b for r, _, b, _ in pairs)
        was = ""
        if args.before:
            old = [round(o / b, 2) for _, _, b, o in pairs]
            was = f"; {args.before.name}'s median ratio {statistics.median(old):.2f} {old}"
        print(
            f"{path.name:18s} {workers} worker(s), {args.control_mode}: {rate:5.1f} successful "
            "demonstrations/min; "
            f"PickCube-v1 runner (1 process) {base:5.1f}/min; median ratio {ratio:.2f} of "
            f"{args.repeats} pair(s) {[round(r / b, 2) for r, _, b, _ in pairs]}{was}; "
            f"{mb:.1f} MB per 100 demonstrations (obs none)",
            flush=True,
        )


if __name__ == "__main__":
    main()
