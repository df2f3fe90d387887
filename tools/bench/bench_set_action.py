#!/usr/bin/env python
"""Benchmark: an agent's ``set_action`` per call, ``envs/fast_control.py`` against ManiSkill's.

One CPU env per robot (its default controller, or ``--control-mode``); in each of ``--rounds``
rounds, the fast ``set_action`` and ManiSkill's (the same agent, the fast one uninstalled for
the block) each time ``--calls`` calls with seeded random actions (uniform in [-1, 1]),
alternating which goes first. Timed by ``time.thread_time`` (CPU time of this thread: a
machine loaded by other jobs slows it less than wall time). Printed: per robot, the median
over rounds of each block's microseconds per call, and the median of each round's ratio.

Usage: python tools/bench/bench_set_action.py [--robots panda fetch ...] [--rounds 5]
                                             [--calls 2000] [--control-mode MODE]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.envs import fast_control  # noqa: E402


def per_call_us(agent, actions: list[torch.Tensor]) -> float:
    start = time.thread_time()
    for action in actions:
        agent.set_action(action)
    return (time.thread_time() - start) / len(actions) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", nargs="+", default=["panda", "so100", "koch-v1.1", "fetch"])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--control-mode", default=None)
    args = parser.parse_args()
    kw = {} if args.control_mode is None else {"control_mode": args.control_mode}
    for uid in args.robots:
        env = gym.make("PickEmbodiedGen-v1", obs_mode="none", robot_uids=uid, **kw)
        env.reset(seed=0)
        agent = env.unwrapped.agent
        fast = agent.set_action
        assert fast_control.installed(agent), "the env did not install the fast set_action"
        rng = np.random.default_rng(0)
        shape = (args.calls, 1, *agent.single_action_space.shape)
        actions = list(torch.from_numpy(rng.uniform(-1, 1, shape).astype(np.float32)))
        times = {"fast": [], "maniskill": []}
        for r in range(args.rounds):
            for which in ("fast", "maniskill") if r % 2 == 0 else ("maniskill", "fast"):
                fast_control.uninstall(agent)
                if which == "fast":
                    agent.set_action = fast
                times[which].append(per_call_us(agent, actions))
        pairs = zip(times["fast"], times["maniskill"], strict=True)
        ratio = statistics.median(f / m for f, m in pairs)
        fast_us, ms_us = (statistics.median(times[k]) for k in ("fast", "maniskill"))
        print(
            f"{uid:16s} {agent.control_mode:22s} ManiSkill {ms_us:7.1f} us  fast {fast_us:6.1f} us"
            f"  ratio {ratio:.3f}"
        )
        env.close()


if __name__ == "__main__":
    main()
