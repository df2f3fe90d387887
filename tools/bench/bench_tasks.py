#!/usr/bin/env python
"""Benchmark: the per-step cost of grading each task kind, against the pick task, same run.

For each layout (default: the shipped pick layout ``default`` and the task layouts), one CPU
env (``obs_mode="state"``, ``reward_mode="normalized_dense"``) is reset with a seed and stepped
a few times with zero actions; then ``evaluate()`` followed by ``compute_normalized_dense_reward``
(what every ``step`` computes) is timed over ``--calls`` calls, in alternating rounds so drift
hits every layout alike. ``--states expert`` times instead the env's own calls of them along the
expert's episode (seed 0, each round): reaching, grasping, carrying, placing, released and at
rest, with live contacts, the mix of states a real episode grades (``--calls`` unused). Prints
the median microseconds per call and the ratio to the first layout (the issue's target: a place
task at most 1.2x the pick task). ``--clock cpu`` times the calls in this thread's CPU time
(``time.thread_time``), which leaves out the time other jobs hold the cores (wall-clock time,
the default, swings by a third on a loaded machine). The ratio is the median over rounds of each
round's ratio, so drift between rounds cancels.

Usage: python tools/bench/bench_tasks.py [--calls 2000] [--rounds 5] [--clock wall|cpu]
       [--states zero|expert] [--layout FILE ...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import torch  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import default_layout  # noqa: E402

TASKS = ("place_box", "place_bowl", "place_two", "move_left")


def make(path: Path, states: str):
    """The env, reset with seed 0; for ``zero``, after five zero steps."""
    mode = dict(control_mode="pd_joint_pos") if states == "expert" else {}  # the expert's
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), obs_mode="state",
                   reward_mode="normalized_dense", **mode)  # fmt: skip
    env.reset(seed=0)
    if states == "zero":
        zero = torch.zeros(env.action_space.shape)
        for _ in range(5):
            env.step(zero)
    return env


def per_call(env, calls: int, clock=time.perf_counter) -> float:
    """Mean time of ``evaluate()`` + the reward per call, over ``calls`` calls at one state."""
    u = env.unwrapped
    action = torch.zeros(env.action_space.shape)
    start = clock()
    for _ in range(calls):
        info = u.evaluate()
        u.compute_normalized_dense_reward(obs=None, action=action, info=info)
    return (clock() - start) / calls * 1e6


def per_expert_call(env, clock=time.perf_counter) -> float:
    """Mean time of the env's own ``evaluate()`` and reward calls over the expert's episode
    (seed 0), timed where the env makes them (live contacts, every phase of the task)."""
    # the solver (mplib, SAPIEN planning) only where the expert's episode is wanted
    from embodied_envs.solvers import PickPlaceSolver

    u = env.unwrapped
    spent, calls = [0.0], [0]

    def timed(method):
        def call(*args, **kwargs):
            start = clock()
            out = method(*args, **kwargs)
            spent[0] += clock() - start
            calls[0] += method.__name__ == "evaluate"
            return out

        return call

    u.evaluate = timed(type(u).evaluate.__get__(u))
    u.compute_normalized_dense_reward = timed(type(u).compute_normalized_dense_reward.__get__(u))
    try:
        env.reset(seed=0)
        if not bool(PickPlaceSolver(env, seed=0).solve().success[0]):
            raise RuntimeError(f"{u.layouts[0].source}: the expert's episode (seed 0) failed")
    finally:
        del u.evaluate, u.compute_normalized_dense_reward
    return spent[0] / calls[0] * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    ap.add_argument("--states", choices=("zero", "expert"), default="zero")
    ap.add_argument("--layout", type=Path, nargs="+", default=None)
    args = ap.parse_args()
    layouts = args.layout or [default_layout()] + [
        default_layout().with_name(f"{n}.json") for n in TASKS
    ]
    envs = [make(p, args.states) for p in layouts]
    times = [[] for _ in envs]
    clock = time.thread_time if args.clock == "cpu" else time.perf_counter
    for r in range(args.rounds):  # the order rotated per round: no layout always first
        for i in range(len(envs)):
            k = (i + r) % len(envs)
            times[k].append(per_expert_call(envs[k], clock) if args.states == "expert"
                            else per_call(envs[k], args.calls, clock))  # fmt: skip
    for path, env, t in zip(layouts, envs, times, strict=True):
        us = statistics.median(t)
        kind = env.unwrapped.tasks[0].kind
        ratio = statistics.median(x / b for x, b in zip(t, times[0], strict=True))
        print(f"{path.stem:12s} {kind:5s} evaluate + reward {us:7.1f} us per step ({args.clock}), "
              f"{ratio:.2f}x {layouts[0].stem}")  # fmt: skip
        env.close()


if __name__ == "__main__":
    main()
