"""The seeded planner (solvers/motion.py): reproducible, collision-free, reaching its goal.

Checked with mplib's own collision queries and forward kinematics, not the planner's."""

import numpy as np
import pytest
from conftest import panda_planner

from embodied_envs.robots import PANDA_HAND
from embodied_envs.solvers.motion import (
    START_COLLIDES,
    SeededPlanner,
    joint_levers,
    straight_line_trajectory,
)

REST = np.array([0.0, np.pi / 8, 0, -5 * np.pi / 8, 0, 3 * np.pi / 4, np.pi / 4, 0.04, 0.04])
DOWN = [0.0, 1.0, 0.0, 0.0]  # TCP pointing down (wxyz)
GOAL = np.array([0.45, 0.35, 0.12, *DOWN])
DT = 0.02


@pytest.fixture(scope="module")
def planner():
    mp = panda_planner()
    # a wall between the rest pose (y = 0) and the goal (y = 0.35), 50 cm tall
    x, z = np.meshgrid(np.linspace(0.25, 0.9, 66), np.linspace(0.0, 0.5, 51))
    wall = np.stack([x.ravel(), np.full(x.size, 0.16), z.ravel()], 1)
    mp.update_point_cloud(wall, radius=0.01)
    return SeededPlanner(mp)


def plan(planner, seed, goal=GOAL):
    return planner.plan_to_pose(goal, REST.copy(), np.random.default_rng(seed), DT, True)


def test_the_wall_blocks_the_straight_line(planner):
    """The scene needs RRT-Connect: the start is free, the direct joint line to every IK
    solution collides."""
    planner.mp.planning_world.set_use_point_cloud(True)
    planner.mp.robot.set_qpos(REST, True)
    assert not planner.mp.check_for_env_collision(qpos=REST, with_point_cloud=True)
    goals, _ = planner.ik(
        planner.mp.transform_goal_to_wrt_base(GOAL), REST, np.random.default_rng(0)
    )
    assert goals
    assert not any(planner.edge_free(REST[:7], g) for g in goals)


def test_same_seed_same_path_other_seed_other_path(planner):
    a, b, c = plan(planner, 7), plan(planner, 7), plan(planner, 9)
    assert a["status"] == b["status"] == c["status"] == "Success", (a["status"], c["status"])
    assert np.array_equal(a["position"], b["position"])  # byte for byte
    assert not np.array_equal(a["position"], c["position"])  # the seed drives the search


@pytest.mark.parametrize("seed", [0, 1, 2, 9])  # 0: the spline grazes, segments run alone
def test_the_path_is_collision_free_and_reaches_the_goal(planner, seed):
    mp = planner.mp
    res = plan(planner, seed)
    assert res["status"] == "Success", res["status"]
    path = res["position"]
    assert np.allclose(path[0], REST[:7], atol=1e-6)
    for q in path:  # every executed waypoint, checked by mplib's own queries
        full = np.concatenate([q, REST[7:]])
        assert not mp.check_for_env_collision(qpos=full, with_point_cloud=True)
        assert not mp.check_for_self_collision(qpos=full)
        assert (q >= planner.lo - 1e-3).all() and (q <= planner.hi + 1e-3).all()
    # no joint jumps more than the planner's velocity limit allows in one control step
    assert np.abs(np.diff(path, axis=0)).max() <= mp.joint_vel_limits.max() * DT * 1.05
    mp.pinocchio_model.compute_forward_kinematics(np.concatenate([path[-1], REST[7:]]))
    pose = mp.pinocchio_model.get_link_pose(planner.link)
    assert np.linalg.norm(pose[:3] - GOAL[:3]) < 2e-3
    assert abs(abs(np.dot(pose[3:], GOAL[3:])) - 1) < 1e-4


def test_ik_solutions_are_distinct_within_limits_and_nearest_first(planner):
    mp = planner.mp
    mp.planning_world.set_use_point_cloud(False)
    mp.robot.set_qpos(REST, True)
    goal = mp.transform_goal_to_wrt_base(np.array([0.5, -0.1, 0.3, *DOWN]))
    sols, _ = planner.ik(goal, REST, np.random.default_rng(3))
    assert len(sols) >= 2
    dist = [np.linalg.norm(s - REST[:7]) for s in sols]
    assert dist == sorted(dist)
    for i, s in enumerate(sols):
        assert (s >= planner.lo).all() and (s <= planner.hi).all()
        assert all(np.linalg.norm(s - t) >= planner.cfg.distinct for t in sols[i + 1 :])
        mp.pinocchio_model.compute_forward_kinematics(np.concatenate([s, REST[7:]]))
        assert np.linalg.norm(mp.pinocchio_model.get_link_pose(planner.link)[:3] - goal[:3]) < 1e-3


def test_an_unreachable_pose_fails_with_a_status(planner):
    res = plan(planner, 0, goal=np.array([2.0, 0.0, 0.5, *DOWN]))  # 2 m away
    assert res["status"].startswith("IK failed"), res["status"]
    assert "position" not in res


def test_a_straight_line_runs_on_the_checked_segment(planner):
    """Without the wall the direct joint line is free: the time-parameterised path stays on
    that segment, forwards only (the planner checks the line once, not the motion again)."""
    mp = planner.mp
    res = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False)
    assert res["status"] == "Success", res["status"]
    path = res["position"]
    start, end = path[0], path[-1]
    along = (path - start) @ (end - start) / np.dot(end - start, end - start)
    off = path - start - along[:, None] * (end - start)
    assert np.abs(off).max() < 1e-6
    assert along.min() > -1e-6 and along.max() < 1 + 1e-6
    assert np.all(np.diff(along) >= -1e-9)  # forwards only
    for q in path[:: max(1, len(path) // 20)]:
        assert not mp.check_for_self_collision(qpos=np.concatenate([q, REST[7:]]))


def test_min_steps_bounds_every_time_parameterised_path(planner):
    """``min_steps`` (the branch-and-bound of the solver's options) is below the waypoints
    the planner runs (TOPP-RA's on detours, the closed form on straight lines), for paths of
    every length, at the solver's joint limits and at mplib's defaults; and it is not loose
    (within 75% on straight lines)."""
    mp = planner.mp
    rng = np.random.default_rng(0)
    defaults = mp.joint_vel_limits.copy(), mp.joint_acc_limits.copy()
    solver = np.array(PANDA_HAND.joint_vel), np.array(PANDA_HAND.joint_acc)
    try:
        for vel, acc in (defaults, solver):
            mp.joint_vel_limits, mp.joint_acc_limits = vel, acc
            tight = []
            for scale in (0.01, 0.05, 0.2, 0.5, 1.0) * 20:
                a = rng.uniform(planner.lo, planner.hi)
                b = np.clip(a + rng.uniform(-1, 1, 7) * scale * (planner.hi - planner.lo),
                            planner.lo, planner.hi)  # fmt: skip
                detour = rng.random() < 0.5
                via = [a, (a + b) / 2 + rng.uniform(-0.3, 0.3, 7) * scale, b] if detour else [a, b]
                if detour:
                    steps = len(mp.TOPP(planner.densify(via), DT)[1])
                else:
                    steps = len(straight_line_trajectory(a, b, vel, acc, DT))
                bound = planner.min_steps(a, [b, b + 10.0], DT)  # the nearer goal counts
                assert bound <= steps, (scale, detour, bound, steps)
                if not detour and steps >= 10:
                    tight.append(bound / steps)
            assert min(tight) > 0.75, tight
    finally:
        mp.joint_vel_limits, mp.joint_acc_limits = defaults


def test_a_straight_line_moves_time_optimally_within_the_limits(planner):
    """The closed-form straight-line motion: a waypoint per control step from rest at one end
    to rest at the other, forwards along the line, every joint within its velocity and
    acceleration limits at every step, one of them at its limit (it is optimal: within a
    step of the duration of TOPP-RA's numerical optimum on the same line, mplib's ``TOPP``).
    60 random lines from 1 mm to 2 rad."""
    vel, acc = np.array(PANDA_HAND.joint_vel), np.array(PANDA_HAND.joint_acc)
    mp = planner.mp
    defaults = mp.joint_vel_limits.copy(), mp.joint_acc_limits.copy()
    mp.joint_vel_limits, mp.joint_acc_limits = vel, acc
    rng = np.random.default_rng(3)
    try:
        for scale in np.repeat([0.001, 0.05, 0.3, 1.0, 2.0], 12):
            a = rng.uniform(planner.lo, planner.hi)
            b = a + rng.uniform(-1, 1, 7) * scale
            q = straight_line_trajectory(a, b, vel, acc, DT)
            assert np.array_equal(q[0], a) and np.allclose(q[-1], b, atol=1e-12)
            s = (q - a) @ (b - a) / np.dot(b - a, b - a)
            assert np.abs(q - a - s[:, None] * (b - a)).max() < 1e-9  # on the line
            assert np.all(np.diff(s) > 0)  # forwards only
            v = np.diff(q, axis=0) / DT  # as the robot steps through it
            assert np.all(np.abs(v) <= vel * (1 + 1e-9)), scale
            dv = np.diff(np.vstack([0 * a, v[:-1]]), axis=0) / DT  # whole steps, from rest
            assert np.all(np.abs(dv) <= acc * (1 + 1e-9)), scale
            if len(q) >= 6:  # a ramp of whole steps: a joint at a limit
                at_limit = (np.abs(v).max(0) >= 0.99 * vel) | (np.abs(dv).max(0) >= 0.99 * acc)
                assert at_limit.any(), scale
            duration = mp.TOPP(planner.densify([a, b]), DT)[-1]
            assert abs((len(q) - 1) - duration / DT) <= 1.0, (scale, len(q), duration / DT)
    finally:
        mp.joint_vel_limits, mp.joint_acc_limits = defaults


def test_within_skips_what_cannot_be_shorter(planner):
    """``within``: no path is planned when the IK solutions show none can be shorter; with
    room the plan is the one planned without a bound."""
    free = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False)
    steps = len(free["position"])
    tight = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False, 1)
    assert tight["status"] == "no path shorter than 1 steps" and "position" not in tight
    roomy = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False, steps + 1)
    assert roomy["status"] == "Success"
    assert np.array_equal(roomy["position"], free["position"])


def test_segments_are_checked_end_first_then_coarse_to_fine():
    """``edge_free`` checks every configuration on a segment once, the far end first and
    then halving strides, so a blocked segment is usually found blocked after a few checks."""
    from embodied_envs.solvers.motion import coarse_to_fine

    assert coarse_to_fine(0) == ()
    for n in range(1, 200):
        order = coarse_to_fine(n)
        assert sorted(order) == list(range(1, n + 1))
        assert order[0] == n
    assert coarse_to_fine(8) == (8, 4, 2, 6, 1, 3, 5, 7)


def test_no_detour_is_searched_from_a_start_that_collides(monkeypatch):
    """Where the start configuration collides and the straight line is blocked, no
    RRT-Connect search runs (one from there cannot grow and would spend all its samples):
    the status says so."""
    mp = panda_planner()
    sp = SeededPlanner(mp)
    mp.pinocchio_model.compute_forward_kinematics(REST)
    hand = mp.pinocchio_model.get_link_pose(sp.link)[:3]
    ball = hand + np.random.default_rng(0).normal(0, 0.03, (400, 3))  # around the hand
    mp.update_point_cloud(ball, radius=0.01)
    mp.planning_world.set_use_point_cloud(True)
    assert not sp.free(REST[:7])

    def searched(*args):
        raise AssertionError("RRT-Connect ran from a colliding start")

    monkeypatch.setattr(SeededPlanner, "rrt_connect", searched)
    res = sp.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, True)
    assert res["status"] == START_COLLIDES and "position" not in res


def test_a_line_that_cannot_beat_within_is_not_checked(planner, monkeypatch):
    """With a bound between ``min_steps`` and the exact length of the straight line, the line
    is refused without a collision check (and no detour is searched); one step more and it is
    checked and planned as without a bound."""
    free = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False)
    steps = len(free["position"])
    checks = []
    real = SeededPlanner.edge_free
    monkeypatch.setattr(
        SeededPlanner, "edge_free", lambda s, a, b: checks.append(1) or real(s, a, b)
    )
    exact = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False, steps)
    assert exact["status"] == f"no straight line shorter than {steps} steps", exact["status"]
    assert not checks
    roomy = planner.plan_to_pose(GOAL, REST.copy(), np.random.default_rng(0), DT, False, steps + 1)
    assert roomy["status"] == "Success" and len(checks) == 1
    assert np.array_equal(roomy["position"], free["position"])


def test_joint_levers_bound_how_far_each_joint_moves_the_robot():
    """Turning one arm joint by ``d`` moves no collision point of the Panda (SAPIEN's own
    link poses and collision shapes) farther than ``d`` times that joint's lever, over 40
    configurations the levers were not sampled on; the levers are tight (some point moves at
    least 80 % of the bound) and follow the arm: the shoulder's about 1 m, the last joint's
    (the hand alone) under 15 cm, so a wrist turn needs a tenth of the checks."""
    import gymnasium as gym
    from mani_skill.utils.geometry.trimesh_utils import get_component_mesh

    import embodied_envs  # noqa: F401
    from embodied_envs.solvers.models import planners as _planners

    env = gym.make("PickEmbodiedGen-v1", control_mode="pd_joint_pos")
    try:
        u = env.unwrapped
        robot = u.agent.robot
        levers = joint_levers(robot, _planners(u)[0])
        assert levers.shape == (7,)
        assert 0.9 < levers[0] < 1.2 and 0.9 < levers[1] < 1.2 and levers[6] < 0.15
        comps = [link._objs[0] for link in robot.get_links()]

        def points(q):
            robot.set_qpos(q[None])
            out = []
            for c in comps:
                mesh = get_component_mesh(c, to_world_frame=False)
                if mesh is not None:
                    m = c.entity_pose.to_transformation_matrix()
                    out.append(mesh.vertices @ m[:3, :3].T + m[:3, 3])
            return np.concatenate(out)

        rng = np.random.default_rng(123)
        lo, hi = robot.get_qlimits()[0].cpu().numpy().T
        d = 0.01
        ratio = np.zeros(7)
        for _ in range(40):
            q = rng.uniform(lo, hi)
            before = points(q)
            for j in range(7):
                turned = q.copy()
                turned[j] += d if turned[j] + d <= hi[j] else -d
                moved = np.linalg.norm(points(turned) - before, axis=1).max()
                assert moved <= d * levers[j] * (1 + 1e-6), (j, moved, d * levers[j])
                ratio[j] = max(ratio[j], moved / (d * levers[j]))
        assert (ratio > 0.8).all(), ratio
        sp = SeededPlanner(_planners(u)[0], levers=levers)
        calls = []
        sp.free = lambda q: calls.append(1) or True
        wrist = np.zeros(7)
        wrist[6] = 1.0  # 1 rad of the last joint alone
        assert sp.edge_free(REST[:7], REST[:7] + wrist)
        assert len(calls) == int(np.ceil(levers[6] / sp.cfg.check_distance)) <= 15
    finally:
        env.close()
