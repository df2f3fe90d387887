"""Corrective copies of demonstrations for behaviour cloning (noise injection with relabelled
targets, as DART and DAgger-style augmentation do): a step's arm joints are moved by a random
offset, the observation is recomputed for the moved arm (its TCP by forward kinematics, the
TCP-to-mover vectors; a grasped mover moves rigidly with the hand), and the step's joint targets
are kept, so the copy's actions lead back onto the demonstrated path.

A demonstration from a planner never shows the arm off its path: a policy whose hand hovers 3 cm
beside the object has seen no state like it and no action that corrects it. Measured on the
default layout's 200 demos (docs/evaluation.md): the demonstrations close the gripper with the
object 0.5 +- 0.1 cm (x) and -0.2 +- 0.2 cm (y) from the TCP; the failed policy episodes hovered
2-4 cm off and pressed the fingers onto the can's rim.

Only a controller whose actions set joint targets relative to the joints (``pd_joint_delta_pos``,
``train_policy.target_frame``) can be relabelled so: the copy's chunk is the same targets less the
moved joints.
"""

from __future__ import annotations

import numpy as np

POSE = 7  # a pose: position (3) and wxyz quaternion (4)
# m: a copy whose TCP is farther than this from the demonstrated step's is taught to keep its
# gripper open (the demonstrations close with the object within 0.2-0.5 cm of the same place)
GRASP_TOL = 0.01


def obs_slices(env) -> dict[str, slice]:
    """Each group of the flat state observation (ManiSkill flattens ``state_dict`` in its order),
    read from ``env`` (made with ``obs_mode="state_dict"``)."""
    if env.unwrapped.obs_mode != "state_dict":
        raise ValueError("obs_slices needs an env made with obs_mode='state_dict'")
    obs, _ = env.reset(seed=0)
    slices, start = {}, 0

    def walk(node):
        nonlocal start
        for key, value in node.items():
            if isinstance(value, dict):
                walk(value)
                continue
            size = int(np.prod(value.shape[1:])) if value.ndim > 1 else 1
            slices[key] = slice(start, start + size)
            start += size

    walk(obs)
    return slices


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of wxyz quaternions ``(N, 4)``."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw],
                    1)  # fmt: skip


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors ``(N, 3)`` rotated by wxyz quaternions ``(N, 4)``."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


class Kinematics:
    """The arm's TCP pose in the world for given joints: the robot's pinocchio model (SAPIEN's),
    in its base frame, placed by the base's recorded pose."""

    def __init__(self, env):
        agent = env.unwrapped.agent
        robot = agent.robot
        self.model = robot._objs[0].create_pinocchio_model()
        names = [link.name for link in robot.get_links()]
        self.tcp = names.index(agent.tcp.name)

    def tcp_world(self, qpos: np.ndarray, base: np.ndarray) -> np.ndarray:
        """``(N, 7)`` TCP poses for joints ``(N, dof)`` and base poses ``(N, 7)``."""
        local = np.empty((len(qpos), POSE))
        for i, q in enumerate(qpos.astype(np.float64)):
            self.model.compute_forward_kinematics(q)
            pose = self.model.get_link_pose(self.tcp)
            local[i, :3], local[i, 3:] = pose.p, pose.q
        p = base[:, :3] + quat_rotate(base[:, 3:], local[:, :3])
        return np.concatenate([p, quat_mul(base[:, 3:], local[:, 3:])], 1)


def corrective_copies(
    obs: np.ndarray, base: np.ndarray, joints: np.ndarray, kin: Kinematics,
    slices: dict[str, slice], sigma: float, copies: int, rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """``copies`` perturbed copies of every step ``obs`` ``(N, D)`` (base poses ``(N, 7)``): the
    observed joints ``joints`` moved by Gaussian offsets of ``sigma`` radians, the TCP pose and
    the TCP-to-mover vectors recomputed, the held mover (where ``is_grasped``: the one nearest
    the TCP) carried rigidly (its pose and its mover-to-goal vector). Returns the copies'
    observations ``(copies*N, D)``, the index of the step each copies (``(copies*N,)``) and the
    joint offsets ``(copies*N, len(joints))``."""
    n = len(obs)
    index = np.tile(np.arange(n), copies)
    offset = rng.normal(0.0, sigma, (len(index), len(joints)))
    new = obs[index].astype(np.float64)
    new[:, joints] += offset
    q = slices["qpos"]
    old_tcp = new[:, slices["tcp_pose"]].copy()
    tcp = kin.tcp_world(new[:, q], base[index])
    new[:, slices["tcp_pose"]] = tcp
    movers = new[:, slices["mover_pose"]].reshape(len(index), -1, POSE)
    mask = new[:, slices["mover_mask"]] > 0.5
    grasped = np.flatnonzero(new[:, slices["is_grasped"]][:, 0] > 0.5)
    if len(grasped):  # the hand's motion carries the held mover: the one nearest the TCP
        reach = np.linalg.norm(movers[grasped, :, :3] - old_tcp[grasped, None, :3], axis=2)
        held = np.where(mask[grasped], reach, np.inf).argmin(1)
        turn = quat_mul(tcp[grasped, 3:], conj(old_tcp[grasped, 3:]))
        was = movers[grasped, held]
        moved_p = tcp[grasped, :3] + quat_rotate(turn, was[:, :3] - old_tcp[grasped, :3])
        movers[grasped, held, :3] = moved_p
        movers[grasped, held, 3:] = quat_mul(turn, was[:, 3:])
        to_goal = new[:, slices["mover_to_goal_pos"]].reshape(len(index), -1, 3)
        to_goal[grasped, held] -= moved_p - was[:, :3]  # the goal stays: goal - mover
        new[:, slices["mover_to_goal_pos"]] = to_goal.reshape(len(index), -1)
        new[:, slices["mover_pose"]] = movers.reshape(len(index), -1)
    to_mover = (movers[:, :, :3] - tcp[:, None, :3]) * mask[:, :, None]
    new[:, slices["tcp_to_mover_pos"]] = to_mover.reshape(len(index), -1)
    return new.astype(np.float32), index, offset.astype(np.float32)
