#!/usr/bin/env python
"""Benchmark: each robot's step and seeded-reset cost, as a ratio to the Panda's, same process.

Issue 35's target: every robot's reset and step cost within 1.2x of the Panda's on the same
layout. One CPU env per robot (the layout given, ``--obs-mode``) is built in one process; then
in ``--rounds`` rounds, each robot in turn (the order rotated every round, so drift hits all
alike) times ``--resets`` seeded resets (``reset(seed=k)``, as evaluation resets; the seeds are
the same for every robot) and then ``--steps`` random-action steps (uniform in [-1, 1], the
robot's default controller). Per round and robot: mean ms per call, and the part of each step
spent in the physics (``scene.step``, timed by wrapping it). Printed: the medians over rounds,
and the median over rounds of each round's ratio to the first robot's (the Panda's).

``--maniskill`` adds ManiSkill's own envs, timed in the same rounds, ratios to their Panda:
``PickCube-v1`` with each robot it supports (panda, so100, fetch), what a robot costs in
ManiSkill's task; ``Empty-v1`` with every robot (the arm alone on a ground plane, set to its
entry's rest joints after each round's resets), what the robot's model itself costs.

Usage: python tools/bench/bench_robots.py [--robots panda so100 ...] [--layout FILE] [--rounds 10]
                                    [--steps 100] [--resets 20] [--obs-mode state ...] [--maniskill]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from dataclasses import dataclass, field

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import mani_skill.envs  # noqa: E402,F401
import numpy as np  # noqa: E402
import torch  # noqa: E402
from bench_reset import reset_ms  # noqa: E402  (tools/bench/: the seeded resets, timed as there)
from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import default_layout  # noqa: E402
from embodied_envs.robots import ROBOTS  # noqa: E402

WHEEL = tuple(uid for uid, r in ROBOTS.items() if r.in_wheel)  # the Panda first
TARGET = 1.2  # issue 35: each robot's reset and step cost at most this times the Panda's


@dataclass
class Subject:
    """One env under test and its per-round timings (ms)."""

    label: str
    env: gym.Env
    rest: tuple[float, ...] | None = None  # joints set after each round's resets (Empty-v1)
    reset: list[float] = field(default_factory=list)
    step: list[float] = field(default_factory=list)
    physics: list[float] = field(default_factory=list)  # of each step

    def __post_init__(self) -> None:
        self.env.reset(seed=0)
        self.physics_s = 0.0
        scene = self.env.unwrapped.scene
        step = scene.step

        def timed_step() -> None:  # the physics alone: ManiSkill's control step calls it
            t = time.perf_counter()
            step()
            self.physics_s += time.perf_counter() - t

        scene.step = timed_step
        self.run_round(5, 2, first_seed=0, rng=np.random.default_rng(0), record=False)

    def run_round(self, steps: int, resets: int, first_seed: int, rng, record=True) -> None:
        """``resets`` seeded resets from ``first_seed``, then ``steps`` random-action steps."""
        ms = reset_ms(self.env, resets, seeded=True, first_seed=first_seed)
        if self.rest is not None:  # Empty-v1 leaves the joints where they were
            agent = self.env.unwrapped.agent
            agent.robot.set_qpos(torch.tensor([self.rest], dtype=torch.float32))
            agent.robot.set_qvel(torch.zeros_like(agent.robot.get_qvel()))
            agent.controller.reset()
        space = self.env.action_space
        actions = rng.uniform(-1, 1, (steps, *space.shape)).astype(space.dtype)
        self.physics_s = 0.0
        t = time.perf_counter()
        for a in actions:
            self.env.step(a)
        elapsed = time.perf_counter() - t
        if record:
            self.reset.append(ms)
            self.step.append(elapsed / steps * 1e3)
            self.physics.append(self.physics_s / steps * 1e3)

    def counts(self) -> str:
        """The robot's articulation size: links / active joints."""
        robot = self.env.unwrapped.agent.robot
        return f"{len(robot.links)}/{len(robot.active_joints)}"

    def fallbacks(self) -> str:
        """Resets whose placement kept the configuration's arrangement (ours only): each tried
        every candidate first."""
        scene = getattr(self.env.unwrapped, "layout_scene", None)
        return "-" if scene is None else str(scene.episodes.fallbacks)


def make(env_id: str, uid: str, obs_mode: str, **kwargs) -> gym.Env:
    return gym.make(env_id, robot_uids=uid, obs_mode=obs_mode, **kwargs)


def median_ratio(ours: list[float], base: list[float]) -> float:
    """The median of the per-round ratios (robust to the machine's drift between rounds)."""
    return statistics.median(o / b for o, b in zip(ours, base, strict=True))


def measure(groups: list[list[Subject]], rounds: int, steps: int, resets: int) -> None:
    """Time every subject in alternating rounds, each round's order rotated by one."""
    flat = [s for group in groups for s in group]
    for r in range(rounds):
        shift = r % len(flat)
        for s in flat[shift:] + flat[:shift]:
            s.run_round(steps, resets, 1000 + r * resets, np.random.default_rng(r))


def report(title: str, group: list[Subject], target: float | None = None) -> None:
    """One table: medians over rounds, and ratios to the group's first env; ``target``: mark
    a reset or step ratio above it."""
    base = group[0]
    print(f"\n{title} (ratios: median over rounds of each round's ratio to {base.label})")
    print(f"{'robot':22s} {'links/joints':>12s} {'reset ms':>9s} {'ratio':>6s} {'step ms':>8s} "
          f"{'ratio':>6s} {'physics ms':>10s} {'ratio':>6s} {'rest ms':>8s} {'ratio':>6s} "
          f"{'fallbacks':>9s}")  # fmt: skip
    for s in group:
        rest = [a - p for a, p in zip(s.step, s.physics, strict=True)]
        base_rest = [a - p for a, p in zip(base.step, base.physics, strict=True)]
        rr, sr = median_ratio(s.reset, base.reset), median_ratio(s.step, base.step)
        flag = " ABOVE" if target is not None and max(rr, sr) > target else ""
        print(
            f"{s.label:22s} {s.counts():>12s} {statistics.median(s.reset):9.2f} {rr:6.2f} "
            f"{statistics.median(s.step):8.2f} {sr:6.2f} {statistics.median(s.physics):10.2f} "
            f"{median_ratio(s.physics, base.physics):6.2f} {statistics.median(rest):8.2f} "
            f"{median_ratio(rest, base_rest):6.2f} {s.fallbacks():>9s}{flag}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--robots", nargs="+", default=list(WHEEL), help="the first is the base")
    ap.add_argument("--layout", default=str(default_layout()))
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--steps", type=int, default=100, help="per robot and round")
    ap.add_argument("--resets", type=int, default=20, help="per robot and round")
    ap.add_argument("--obs-mode", nargs="+", default=["state"])
    ap.add_argument("--maniskill", action="store_true", help="also PickCube-v1 per robot")
    args = ap.parse_args()
    for obs_mode in args.obs_mode:
        ours = [
            Subject(uid, make("PickEmbodiedGen-v1", uid, obs_mode, layout_file=args.layout))
            for uid in args.robots
        ]
        groups = {"PickEmbodiedGen-v1": ours}
        if args.maniskill:
            cube = [u for u in args.robots if u in PickCubeEnv.SUPPORTED_ROBOTS]
            groups["ManiSkill PickCube-v1"] = [
                Subject(f"{uid} (PickCube)", make("PickCube-v1", uid, obs_mode)) for uid in cube
            ]
            groups["ManiSkill Empty-v1, from each entry's rest joints"] = [
                Subject(f"{uid} (Empty)", make("Empty-v1", uid, obs_mode), ROBOTS[uid].rest_qpos)
                for uid in args.robots
            ]
        measure(list(groups.values()), args.rounds, args.steps, args.resets)
        print(
            f"\nobs_mode={obs_mode}, CPU, {args.rounds} rounds of {args.resets} seeded resets and "
            f"{args.steps} random-action steps per env; layout {os.path.basename(args.layout)}"
        )
        for title, group in groups.items():
            report(title, group, TARGET if group is ours else None)
            for s in group:
                s.env.close()


if __name__ == "__main__":
    main()
