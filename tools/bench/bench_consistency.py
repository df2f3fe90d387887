#!/usr/bin/env python
"""Benchmark: do nearby starts give nearby expert trajectories? (issue 47, docs/expert.md)

For each seed the expert runs the episode twice: as the seed places it, and with the first
mover shifted ``--shift`` m in a direction drawn from the seed and turned ``--turn`` degrees
about the vertical (a nearby start: the same layout, robot and goal). Per layout it prints:

- detours: moves per episode that ran an RRT-Connect path (the rest: straight joint lines
  and screw moves), and RRT-Connect searches per episode;
- grasp changes: pairs whose first grasp, in the object's frame, moved more than 1 cm or turned
  more than 15 degrees (another grasp), of them flips: turned more than 90 degrees;
- branch changes: pairs whose arm stood, at its first grasp, more than 0.5 rad (largest joint)
  apart with the same grasp (the IK took another branch);
- spread: the joint-target trajectories' distance, RMS over the episode with both resampled to
  the same 101 instants (rad), median and 90th percentile over pairs, and how many exceed 0.2;
- success and mean steps of both runs.

``--set FIELD=VALUE`` sets a ``SolverConfig`` field (e.g. ``--set consistent=False``: the
former, diverse expert). Usage: python tools/bench/bench_consistency.py [--seeds 20]
[--layout FILE ...] [--shift 0.01] [--turn 5] [--set FIELD=VALUE ...]
"""

from __future__ import annotations

import argparse
import ast
import os
import time
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import sapien  # noqa: E402
from mani_skill.utils.structs.pose import Pose  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import shipped_layouts  # noqa: E402
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402
from embodied_envs.solvers.driver import ArmDriver  # noqa: E402
from embodied_envs.solvers.motion import SeededPlanner  # noqa: E402
from embodied_envs.solvers.pick_place import SolverConfig  # noqa: E402

MOVED = 0.01  # m: a grasp moved this far on the object is another grasp
TURNED = 15.0  # deg: or turned this far
FLIP = 90.0  # deg: a grasp turned this far is a flip
BRANCH = 0.5  # rad: the arm's largest joint this far apart at the same grasp is another branch
SPREAD = 0.2  # rad RMS: trajectories farther apart are counted
SAMPLES = 101  # instants both trajectories are resampled to


class Probe:
    """Counts an episode's RRT-Connect searches and the methods of the paths it runs."""

    def __init__(self):
        self.reset()
        planned, rrt, execute = (SeededPlanner.plan_to_pose, SeededPlanner.rrt_connect,
                                 ArmDriver._execute)  # fmt: skip
        probe = self

        def rrt_connect(planner, *a, **k):
            probe.searching = True
            probe.searches += 1
            return rrt(planner, *a, **k)

        def plan_to_pose(planner, *a, **k):
            probe.searching = False
            res = planned(planner, *a, **k)
            if res.get("status") == "Success":
                probe.methods.append((res["position"], "rrt" if probe.searching else "line"))
            return res

        def _execute(solver, paths, *a, **k):
            for p in paths:
                if p is not None:
                    how = next((m for q, m in probe.methods if q is p), "screw")
                    probe.ran[how] = probe.ran.get(how, 0) + 1
            return execute(solver, paths, *a, **k)

        SeededPlanner.rrt_connect, SeededPlanner.plan_to_pose = rrt_connect, plan_to_pose
        ArmDriver._execute = _execute

    def reset(self):
        self.searching, self.searches, self.methods, self.ran = False, 0, [], {}


def first_grasp(solver) -> dict:
    """Wraps the solver's ``_per_env``: the first approach's chosen pose and arm targets."""
    out, per_env = {}, solver._per_env

    def wrapped(stage, *a, **k):
        chosen = per_env(stage, *a, **k)
        if stage == "approach" and "pose" not in out and chosen[0] is not None:
            out["pose"], out["q"] = chosen[0], solver.command[0].copy()
            out["on_object"] = out["object"].inv() * chosen[0]
        return chosen

    def before(stage, *a, **k):
        if stage == "approach" and "pose" not in out:
            raw = solver.target.pose.raw_pose[0].cpu().numpy().astype(np.float64)
            out["object"] = sapien.Pose(raw[:3], raw[3:])
        return wrapped(stage, *a, **k)

    solver._per_env = before
    return out


def episode(env, seed: int, cfg: SolverConfig, shift: float, turn: float, probe: Probe):
    env.reset(seed=seed)
    u = env.unwrapped
    if shift or turn:  # the nearby start: the first mover moved and turned
        rng = np.random.default_rng([seed, 47])
        angle = rng.uniform(0, 2 * np.pi)
        actor = u.env_actors["env0"][u.tasks[0].objects[0]]
        pose = actor.pose.sp
        yaw = np.deg2rad(turn) * rng.choice([-1, 1])
        spin = sapien.Pose(q=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
        moved = sapien.Pose(pose.p + shift * np.array([np.cos(angle), np.sin(angle), 0]))
        actor.set_pose(Pose.create(moved * spin * sapien.Pose(q=pose.q)))
    actions, step = [], env.step

    def recording(action):
        actions.append(np.asarray(action, np.float64).reshape(-1)[:7].copy())
        return step(action)

    env.step = recording
    probe.reset()
    solver = PickPlaceSolver(env, cfg, seed=seed)
    grasp = first_grasp(solver)
    result = solver.solve()
    env.step = step
    success = bool(u.evaluate()["success"][0])
    return dict(success=success, steps=result.steps, actions=np.array(actions), grasp=grasp,
                searches=probe.searches, ran=dict(probe.ran))  # fmt: skip


def hand_angles(pose: sapien.Pose) -> tuple[float, float]:
    """The grasp frame's closing direction's yaw (deg) and its approach's tilt from straight
    down (deg)."""
    rot = pose.to_transformation_matrix()[:3, :3]
    closing, approach = rot[:, 1], rot[:, 2]
    yaw = np.degrees(np.arctan2(closing[1], closing[0]))
    tilt = np.degrees(np.arccos(np.clip(-approach[2], -1, 1)))
    return yaw, tilt


def spread(a: np.ndarray, b: np.ndarray) -> float:
    t = np.linspace(0, 1, SAMPLES)
    ra = np.stack([np.interp(t, np.linspace(0, 1, len(a)), a[:, j]) for j in range(a.shape[1])], 1)
    rb = np.stack([np.interp(t, np.linspace(0, 1, len(b)), b[:, j]) for j in range(b.shape[1])], 1)
    return float(np.sqrt(((ra - rb) ** 2).sum(1).mean()))


def parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, value = item.split("=", 1)
        out[key] = ast.literal_eval(value)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first", type=int, default=0, help="the first seed")
    ap.add_argument("--layout", type=Path, nargs="+", default=None)
    ap.add_argument("--shift", type=float, default=0.01)
    ap.add_argument("--turn", type=float, default=5.0)
    ap.add_argument("--set", nargs="*", default=[], dest="sets")
    ap.add_argument("--verbose", action="store_true", help="a line per pair")
    args = ap.parse_args()
    cfg = SolverConfig(**parse_sets(args.sets))
    probe = Probe()
    for path in args.layout or shipped_layouts():
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), control_mode="pd_joint_pos")
        t0 = time.perf_counter()
        seeds = range(args.first, args.first + args.seeds)
        runs = [(episode(env, s, cfg, 0, 0, probe),
                 episode(env, s, cfg, args.shift, args.turn, probe)) for s in seeds]  # fmt: skip
        env.close()
        eps = [e for pair in runs for e in pair]
        detours = np.mean([e["ran"].get("rrt", 0) for e in eps])
        moves = np.mean([sum(e["ran"].values()) for e in eps])
        with_detour = sum(e["ran"].get("rrt", 0) > 0 for e in eps)
        searches = np.mean([e["searches"] for e in eps])
        changes = flips = branches = 0
        spreads = []
        for seed, (a, b) in enumerate(runs, args.first):
            spreads.append(spread(a["actions"], b["actions"]))
            if args.verbose:
                dq = (np.abs(a["grasp"]["q"] - b["grasp"]["q"]).round(2).tolist()
                      if "q" in a["grasp"] and "q" in b["grasp"] else None)  # fmt: skip
                angles = [hand_angles(e["grasp"]["pose"]) if "pose" in e["grasp"] else None
                          for e in (a, b)]  # fmt: skip
                print(f"  seed {seed}: spread {spreads[-1]:.3f}, grasp (yaw, tilt) {angles}, "
                      f"joints apart {dq}, moves {a['ran']} / {b['ran']}, steps {a['steps']} / "
                      f"{b['steps']}, success {a['success']} / {b['success']}")
            if "pose" not in a["grasp"] or "pose" not in b["grasp"]:
                continue
            rel = a["grasp"]["on_object"].inv() * b["grasp"]["on_object"]
            turned = np.degrees(2 * np.arccos(np.clip(abs(rel.q[0]), 0, 1)))
            changed = np.linalg.norm(rel.p) > MOVED or turned > TURNED
            changes += changed
            flips += turned > FLIP
            far = np.abs(a["grasp"]["q"] - b["grasp"]["q"]).max() > BRANCH
            branches += far and not changed
        s = np.array(spreads)
        ok = sum(e["success"] for e in eps)
        steps = np.mean([e["steps"] for e in eps if e["success"]] or [0])
        wall = (time.perf_counter() - t0) / len(eps)
        print(
            f"{path.name:16s} pairs {args.seeds}: detours {detours:.2f}/episode of {moves:.1f} "
            f"moves ({with_detour}/{len(eps)} episodes), RRT searches {searches:.2f}/episode; "
            f"grasp changes {changes}/{args.seeds} (flips {flips}), branch changes "
            f"{branches}/{args.seeds}; spread median {np.median(s):.3f} "
            f"p90 {np.percentile(s, 90):.3f} rad, "
            f">{SPREAD}: {(s > SPREAD).sum()}/{args.seeds}; success {ok}/{len(eps)}, "
            f"mean {steps:.0f} steps, {wall:.1f} s/episode",
            flush=True,
        )


if __name__ == "__main__":
    main()
