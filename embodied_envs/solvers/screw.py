"""Straight moves of the hand (screw motions), timed in closed form.

mplib's ``Planner.plan_screw`` walks the hand along the screw motion to a pose in joint steps of
``qpos_step`` rad (the Jacobian's pseudo-inverse), checking each configuration for collisions,
then fits TOPP-RA's spline through those few waypoints: 10-70 ms a move, most of a short move's
plan (a descent, a lift, a lowering, a withdrawal; 9 % of a place episode's time). Here the
same walk is timed by :func:`polyline_trajectory`: the waypoints' polyline run from rest to
rest, every joint within its velocity and acceleration limits, exact and in closed form, as
``motion.straight_line_trajectory`` runs a line.
"""

from __future__ import annotations

import mplib
import numpy as np
from scipy.spatial.transform import Rotation


def rest_to_rest(speed: float, rate: float, time_step: float) -> np.ndarray:
    """The fraction ``u`` of a path covered at each control step, from rest at 0 to rest at 1:
    ``du/dt`` at most ``speed`` and ``d2u/dt2`` at most ``rate``, time-optimal (accelerate,
    cruise, brake; a triangle when the path is too short to reach the speed), sampled every
    ``time_step`` from its start, then its end."""
    ramp = min(speed / rate, np.sqrt(1 / rate))  # seconds accelerating (and braking)
    speed = rate * ramp
    duration = 1 / speed + ramp
    t = np.append(np.arange(0.0, duration, time_step), duration)
    return np.where(
        t < ramp,
        rate * t**2 / 2,
        np.where(t > duration - ramp, 1 - rate * (duration - t) ** 2 / 2, speed * (t - ramp / 2)),
    )


def polyline_trajectory(
    path: np.ndarray, vel: np.ndarray, acc: np.ndarray, time_step: float
) -> np.ndarray:
    """The joint waypoints ``path (n, dof)`` joined by straight segments, run from rest to rest
    with every joint within ``vel`` and ``acc`` on every segment (the path's progress bounded
    by its tightest segment), sampled every ``time_step``: ``(T, dof)``, a waypoint per control
    step, the first ``path[0]`` and the last ``path[-1]``. Two waypoints: a straight line,
    timed as ``motion.straight_line_trajectory`` times it.

    Progress is measured in seconds at full speed (each segment's longest joint move over its
    limit), so a short last segment is not crossed slower than the others.
    """
    path = np.asarray(path, dtype=np.float64)
    vel, acc = np.asarray(vel, np.float64), np.asarray(acc, np.float64)
    moves = np.diff(path, axis=0)
    keep = np.abs(moves).max(axis=1) > 0
    path = np.concatenate([path[:1], path[1:][keep]])
    moves = moves[keep]
    if not len(moves):
        return path[:1].copy()
    seconds = (np.abs(moves) / vel).max(axis=1)  # each segment at full speed
    length = seconds.sum()
    # d2s/dt2 at most (s: seconds at full speed): per segment, each joint's share of it
    with np.errstate(divide="ignore"):
        rate = float(np.min(acc * seconds[:, None] / np.abs(moves))) / length
    u = rest_to_rest(1.0 / length, rate, time_step) * length
    ends = np.cumsum(seconds)
    k = np.minimum(np.searchsorted(ends, u, side="right"), len(moves) - 1)
    frac = np.clip((u - (ends[k] - seconds[k])) / seconds[k], 0.0, 1.0)
    out = path[k] + frac[:, None] * moves[k]
    out[-1] = path[-1]
    return out


SCREW_END_TOLERANCE = 0.003  # m, a five-joint arm's screw walk ends at most this far from its goal


def screw_waypoints(planner: mplib.Planner, goal_base: np.ndarray, qpos: np.ndarray,
                    qpos_step: float = 0.1) -> tuple[np.ndarray | None, str]:  # fmt: skip
    """mplib's ``plan_screw`` walk (mplib 0.1.1, step for step) from ``qpos`` (every joint of
    the planner's robot) to ``goal_base`` ([x, y, z, qw, qx, qy, qz] of the move group's link
    in the robot base frame), without its time parameterisation: the move group's
    configurations ``(n, dof)`` (the first is ``qpos``'s), and "" ; or None and why not (a
    configuration collides or leaves the joint limits, or the walk stalls). The planning
    world's collision settings (point cloud, attached tool) are the caller's."""
    model = planner.pinocchio_model
    q = np.asarray(qpos, dtype=np.float64).copy()
    planner.robot.set_qpos(q, True)
    ee = planner.link_name_2_idx[planner.move_group]
    model.compute_forward_kinematics(q)
    now = model.get_link_pose(ee)
    # the relative transform's exponential coordinates (twist * angle), as mplib computes them
    r_now = Rotation.from_quat(np.roll(now[3:], -1))
    r_goal = Rotation.from_quat(np.roll(goal_base[3:], -1))
    rel_rot = (r_goal * r_now.inv()).as_matrix()
    rel_p = goal_base[:3] - rel_rot @ now[:3]
    trace = np.trace(rel_rot)
    if np.isclose(trace, 3):
        omega, theta = np.zeros(3), 1.0
    elif np.isclose(trace, -1):
        return None, "screw plan failed (a half turn)"
    else:
        theta = float(np.arccos((trace - 1) / 2))
        omega = np.array([rel_rot[2, 1] - rel_rot[1, 2], rel_rot[0, 2] - rel_rot[2, 0],
                          rel_rot[1, 0] - rel_rot[0, 1]]) / (2 * np.sin(theta))  # fmt: skip
    ss = np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]])
    inv_left = np.eye(3) / theta - 0.5 * ss + (1 / theta - 0.5 / np.tan(theta / 2)) * ss @ ss
    twist = np.concatenate([inv_left @ rel_p, omega]) * theta
    idx = np.asarray(planner.move_group_joint_indices)
    limits = np.asarray(planner.joint_limits, dtype=np.float64)
    path = [q[idx].copy()]
    while True:
        model.compute_full_jacobian(q)
        jac = model.get_link_jacobian(ee, local=False)
        dq = np.linalg.pinv(jac) @ twist
        dq *= qpos_step / np.linalg.norm(dq)
        dtwist = jac @ dq
        last = np.linalg.norm(dtwist) > np.linalg.norm(twist)
        if last:
            ratio = np.linalg.norm(twist) / np.linalg.norm(dtwist)
            dq, dtwist = dq * ratio, dtwist * ratio
        q = q + dq
        twist = twist - dtwist
        inside = np.all((q >= limits[:, 0] - 1e-3) & (q <= limits[:, 1] + 1e-3))
        planner.planning_world.set_qpos_all(q[idx])
        if np.linalg.norm(dtwist) < 1e-4 or not inside or planner.planning_world.collide():
            return None, "screw plan failed"
        path.append(q[idx].copy())
        if last:
            # an arm of fewer than six joints walks the twist only in the least-squares sense:
            # its end may stand off the goal (the Koch's descent onto a can: 2.3 cm); six or
            # more walk it to first order (the Panda: a few mm, as mplib's), unchecked
            model.compute_forward_kinematics(q)
            off = float(np.linalg.norm(model.get_link_pose(ee)[:3] - goal_base[:3]))
            if len(idx) < 6 and off > SCREW_END_TOLERANCE:
                return None, f"screw plan failed (ends {off:.3f} m off the goal)"
            return np.asarray(path), ""
