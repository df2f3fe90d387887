"""The consistent expert (``SolverConfig.consistent``, the default; docs/expert.md, "Consistent
demonstrations"): a nearby start (the banana shifted 1 cm and turned 5 degrees) takes the same
grasp on the object and a nearby path; the diverse expert (``consistent=False``, ``collect
--diverse``), the former one, takes another grasp there."""

import gymnasium as gym
import numpy as np
import pytest
import sapien
from conftest import DATA
from mani_skill.utils.structs.pose import Pose

import embodied_envs  # noqa: F401
from embodied_envs.solvers import PickPlaceSolver
from embodied_envs.solvers.pick_place import SolverConfig

SEED = 2  # round_table: the diverse expert's grasp moves 5 cm along the banana there
SHIFT, TURN = 0.01, np.deg2rad(5.0)  # m, rad: the nearby start (tools/bench/bench_consistency.py's)
SAME_AT, SAME_TURN = 0.01, np.deg2rad(15.0)  # m, rad: a grasp moved or turned less is the same


def first_grasp_on_object(env, config: SolverConfig, nearby: bool) -> sapien.Pose:
    """The first approach's grasp in the banana's frame, the episode started as the seed
    places it or (``nearby``) from the nearby start; the episode run to its end."""
    env.reset(seed=SEED)
    u = env.unwrapped
    actor = u.env_actors["env0"][u.tasks[0].objects[0]]
    if nearby:  # as the benchmark draws it for the seed
        rng = np.random.default_rng([SEED, 47])
        angle, yaw = rng.uniform(0, 2 * np.pi), TURN * rng.choice([-1, 1])
        pose = actor.pose.sp
        spin = sapien.Pose(q=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
        moved = sapien.Pose(pose.p + SHIFT * np.array([np.cos(angle), np.sin(angle), 0]))
        actor.set_pose(Pose.create(moved * spin * sapien.Pose(q=pose.q)))
    solver, out = PickPlaceSolver(env, config, seed=SEED), {}
    per_env = solver._per_env

    def recorded(stage, *args, **kwargs):
        if stage == "approach" and not out:
            raw = solver.target.pose.raw_pose[0].cpu().numpy().astype(np.float64)
            out["object"] = sapien.Pose(raw[:3], raw[3:])
        chosen = per_env(stage, *args, **kwargs)
        if stage == "approach" and "grasp" not in out:
            out["grasp"] = out["object"].inv() * chosen[0]
        return chosen

    solver._per_env = recorded
    solver.solve()
    assert bool(u.evaluate()["success"][0])
    return out["grasp"]


@pytest.mark.parametrize("consistent", [True, False])
def test_a_nearby_start_takes_the_same_grasp_only_in_the_consistent_expert(consistent):
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(DATA / "layouts" / "round_table.json"),
                   control_mode="pd_joint_pos")  # fmt: skip
    try:
        config = SolverConfig(consistent=consistent)
        a, b = (first_grasp_on_object(env, config, nearby) for nearby in (False, True))
    finally:
        env.close()
    apart = a.inv() * b
    same = np.linalg.norm(apart.p) < SAME_AT and 2 * np.arccos(min(abs(apart.q[0]), 1)) < SAME_TURN
    assert same == consistent, (a, b)
