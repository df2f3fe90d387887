"""Screw moves timed in closed form (solvers/screw.py): mplib's walk, at the joint limits.

Checked against mplib's own ``plan_screw`` and forward kinematics."""

import numpy as np
import pytest
from conftest import panda_planner

from embodied_envs.robots import PANDA_HAND
from embodied_envs.solvers.motion import straight_line_trajectory
from embodied_envs.solvers.screw import polyline_trajectory, screw_waypoints

REST = np.array([0.0, np.pi / 8, 0, -5 * np.pi / 8, 0, 3 * np.pi / 4, np.pi / 4, 0.04, 0.04])
DT = 0.02
VEL, ACC = np.array(PANDA_HAND.joint_vel), np.array(PANDA_HAND.joint_acc)


@pytest.fixture(scope="module")
def planner():
    mp = panda_planner()
    mp.joint_vel_limits, mp.joint_acc_limits = VEL, ACC
    return mp


def hand(mp, q):
    mp.pinocchio_model.compute_forward_kinematics(np.concatenate([q, REST[7:]]))
    return mp.pinocchio_model.get_link_pose(mp.link_name_2_idx[mp.move_group])


def test_two_waypoints_are_a_straight_line():
    """A polyline of one segment is timed exactly as ``straight_line_trajectory`` times it."""
    rng = np.random.default_rng(0)
    for scale in (0.001, 0.05, 0.3, 1.0):
        a = rng.uniform(-1, 1, 7)
        b = a + rng.uniform(-1, 1, 7) * scale
        line = straight_line_trajectory(a, b, VEL, ACC, DT)
        assert np.allclose(polyline_trajectory(np.stack([a, b]), VEL, ACC, DT), line, atol=1e-12)


def test_a_polyline_runs_along_its_segments_within_the_speed_limits():
    """Three bent segments of different lengths: from the first waypoint to the last, each
    sample on a segment, forwards, every joint within its velocity limit at every step and
    one at its limit while cruising."""
    path = np.array([[0, 0, 0, 0, 0, 0, 0], [0.2, 0.1, 0, 0, 0, 0, 0],
                     [0.3, 0.4, 0.1, 0, 0, 0, 0], [0.31, 0.45, 0.1, 0.02, 0, 0, 0]])  # fmt: skip
    q = polyline_trajectory(path, VEL, ACC, DT)
    assert np.array_equal(q[0], path[0]) and np.array_equal(q[-1], path[-1])
    assert np.all(np.abs(np.diff(q, axis=0)) <= VEL * DT * (1 + 1e-9))
    moves = np.diff(path, axis=0)
    progress = []
    for p in q:  # the segment it lies on, and how far along
        for k, (a, m) in enumerate(zip(path[:-1], moves, strict=True)):
            f = np.dot(p - a, m) / np.dot(m, m)
            if -1e-9 <= f <= 1 + 1e-9 and np.abs(a + f * m - p).max() < 1e-9:
                progress.append(k + f)
                break
        else:
            raise AssertionError(f"{p} is on no segment")
    assert np.all(np.diff(progress) >= -1e-9)
    assert len(q) - 1 >= (np.abs(moves) / VEL).max(axis=1).sum() / DT  # never faster
    assert (np.abs(np.diff(q, axis=0)) >= 0.99 * VEL * DT).any()  # a joint cruises at its limit


def test_a_screw_walk_ends_where_mplibs_ends_at_the_pose(planner):
    """The walk ends where mplib's ``plan_screw`` ends, near the goal (the Jacobian steps are
    first order: a few millimetres off, as mplib's), in joint steps of at most 0.1 rad; its
    timing keeps to the limits."""
    start = hand(planner, REST[:7])
    for shift in ([0, 0, -0.08], [0.05, 0.03, 0.02], [0, 0, 0.1]):
        goal = np.concatenate([start[:3] + shift, start[3:]])
        path, why = screw_waypoints(planner, goal, REST.copy())
        assert why == "" and np.array_equal(path[0], REST[:7])
        assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() <= 0.1 + 1e-9
        reached = hand(planner, path[-1])
        assert np.abs(reached[:3] - goal[:3]).max() < 5e-3
        theirs = planner.plan_screw(goal, REST.copy(), time_step=DT)
        assert theirs["status"] == "Success"
        assert np.allclose(path[-1], theirs["position"][-1], atol=1e-6)
        q = polyline_trajectory(path, VEL, ACC, DT)
        assert np.all(np.abs(np.diff(q, axis=0)) <= VEL * DT * (1 + 1e-9))


def test_a_screw_walk_into_the_floor_is_refused(planner):
    """A configuration on the way that collides ends the walk with mplib's status."""
    floor = np.stack(np.meshgrid(np.linspace(0.2, 0.7, 51), np.linspace(-0.3, 0.3, 61)), -1)
    cloud = np.concatenate([floor.reshape(-1, 2), np.full((floor[..., 0].size, 1), 0.1)], 1)
    planner.update_point_cloud(cloud, radius=0.01)
    planner.planning_world.set_use_point_cloud(True)
    try:
        start = hand(planner, REST[:7])
        goal = np.concatenate([[start[0], start[1], 0.05], start[3:]])  # below the floor
        path, why = screw_waypoints(planner, goal, REST.copy())
        assert path is None and why == "screw plan failed"
    finally:
        planner.planning_world.set_use_point_cloud(False)
