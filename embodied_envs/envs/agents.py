"""What the env asks of a robot through ManiSkill: may it be loaded, where is its TCP, does it
grasp. The robots' numbers are in ``embodied_envs/robots.py``; this module reads the agent
classes (their model files, their ``is_grasping``) and the loaded agents.
"""

from __future__ import annotations

import os

import mani_skill.agents.robots  # noqa: F401  (registers ManiSkill's agents)
import numpy as np
import torch
from mani_skill.agents.base_agent import BaseAgent
from mani_skill.agents.registration import REGISTERED_AGENTS
from mani_skill.utils.structs.pose import Pose
from sapien import physx

from embodied_envs import robots
from embodied_envs.envs import contacts
from embodied_envs.internals import link_components


def model_file(uid: str) -> str | None:
    """The model file ManiSkill's agent class ``uid`` loads (URDF or MJCF), or None."""
    cls = REGISTERED_AGENTS[uid].agent_cls
    return getattr(cls, "urdf_path", None) or getattr(cls, "mjcf_path", None)


def check_robot(uid) -> None:
    """Refuse, in one line, a robot the env cannot load before anything is simulated: not a
    string, a ManiSkill agent without a gripper's grasp check, one this package has no entry
    for, or one whose model file is not on this machine (ManiSkill downloads some separately).

    Raises:
        ValueError: naming the robot, why, and the fix.
    """
    supported = list(robots.SUPPORTED_ROBOTS)
    if isinstance(uid, list | tuple) and len(uid) == 2 and all(isinstance(u, str) for u in uid):
        for one in uid:  # two arms (ManiSkill's multi-agent env), each a supported robot
            check_robot(one)
        return
    if not isinstance(uid, str):
        raise ValueError(
            f"robot_uids={uid!r}: PickEmbodiedGen-v1 loads one robot or two, named by their "
            f"ManiSkill uids (a string, or a list of two); use {supported}"
        )
    agent = REGISTERED_AGENTS.get(uid)
    if uid not in robots.ROBOTS:
        # BaseAgent.is_grasping raises NotImplementedError: only arms with a gripper override it
        if agent is not None and agent.agent_cls.is_grasping is BaseAgent.is_grasping:
            raise ValueError(
                f"robot_uids={uid!r}: ManiSkill's {uid} has no gripper (its agent class "
                f"{agent.agent_cls.__name__} does not define is_grasping), and every task of "
                f"PickEmbodiedGen-v1 grasps an object. Fix: use an arm with a gripper, one of "
                f"{supported}"
            )
        what = "is not supported" if agent is not None else "is not a ManiSkill robot uid"
        raise ValueError(f"robot_uids={uid!r} {what}; use one of {supported}")
    path = model_file(uid) if agent is not None else None
    if path is None or not os.path.exists(path):
        raise ValueError(
            f"robot_uids={uid!r}: its model ({path}) is not on this machine; ManiSkill "
            f"downloads it separately. Fix: `{robots.DOWNLOAD_COMMAND.format(uid=uid)}` "
            "(set MS_ASSET_DIR first to choose where it goes), or use one of "
            f"{[r for r in supported if robots.ROBOTS[r].in_wheel]}"
        )


def set_pads(agent, entry: robots.Robot) -> None:
    """Give the links ManiSkill's agent class pads with its ``gripper`` material (its
    ``urdf_config``) ``entry.pad_friction``, static and dynamic, in every parallel env, before
    anything is simulated; nothing where the entry keeps ManiSkill's.

    Raises:
        ValueError: the entry sets a friction and the agent names no such link it has.
    """
    if entry.pad_friction is None:
        return
    names = {name for name, cfg in (agent.urdf_config or {}).get("link", {}).items()
             if cfg.get("material") == "gripper"}  # fmt: skip
    links = [link for link in agent.robot.links if link.name in names]
    if not links:
        raise ValueError(
            f"robots.py: {entry.uid}'s pad_friction={entry.pad_friction} has no pads to go on: "
            f"ManiSkill's {type(agent).__name__} gives no link of it the 'gripper' material. "
            "Fix: set its pad_friction to None"
        )
    mu = entry.pad_friction
    material = physx.PhysxMaterial(static_friction=mu, dynamic_friction=mu, restitution=0.0)
    for link in links:
        for shape in (s for obj in link_components(link) for s in obj.collision_shapes):
            shape.set_physical_material(material)


def all_agents(env) -> list:
    """The env's agents: ManiSkill's ``MultiAgent.agents`` for several robots, else the one."""
    return list(getattr(env.agent, "agents", [env.agent]))


def opposite_spots(spots: np.ndarray, normals, offsets, lo, hi, margin: float) -> np.ndarray:
    """A second arm's spots ``(n, 7)`` across the table from ``spots (n, 7)``: on the ray from
    each spot through its table top's centre (the middle of ``lo``, ``hi``), ``margin`` inside
    the far edge of the top (half-planes ``normals @ x >= offsets``), facing the centre."""
    spots = np.asarray(spots, dtype=np.float64)
    centre = (np.asarray(lo) + np.asarray(hi)) / 2
    d = centre - spots[:, :2]
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    n, o = np.asarray(normals, np.float64), np.asarray(offsets, np.float64)
    nd = np.einsum("bej,bj->be", n, d)
    room = np.einsum("bej,bj->be", n, centre) - o  # >= 0 inside
    t = np.where(nd < -1e-9, room / np.maximum(-nd, 1e-9), np.inf).min(1)
    out = spots.copy()
    out[:, :2] = centre + (t - margin)[:, None] * d
    yaw = np.arctan2(-d[:, 1], -d[:, 0])  # facing back, toward the centre
    out[:, 3:] = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1)
    return out.astype(np.float32)


def arm_bases(entries, spots: np.ndarray, top, margin: float, floor_z: float, device):
    """Each arm's spots and base poses: the first arm at the layout's ``spots (n, 7)``, a second
    across the table (:func:`opposite_spots`; ``top``: the table tops' half-planes and bounds,
    ``margin`` inside the far edge); the bases at each spot, or by the entry's offsets from it
    (``Robot.base_poses``), as tensors on ``device``.

    Returns:
        ``(spots, bases)``: a list per arm of ``(n, 7)`` arrays, and of ``(n, 7)`` tensors.
    """
    arm_spots = [spots]
    if len(entries) > 1:
        arm_spots.append(opposite_spots(spots, top.normals, top.offsets, top.lo, top.hi, margin))
    bases = [
        torch.as_tensor(r.base_poses(sp, floor_z), device=device)
        for r, sp in zip(entries, arm_spots, strict=True)
    ]
    return arm_spots, bases


def reset_arms(
    arms, entries, bases, rests, env_idx: torch.Tensor, noise: float, joint_noise
) -> None:
    """Stand each arm at its base pose ``bases (n, 7)`` for the envs ``env_idx`` at its rest
    joints ``rests`` (one array per arm: ``robot_init_qpos``, else :func:`default_rest`) plus
    ``noise`` times ``joint_noise (b, J)`` (standard normal draws) on its entry's
    ``noise_joints``; the fingers stay open."""
    for agent, entry, base, rest in zip(arms, entries, bases, rests, strict=True):
        agent.robot.set_root_pose(Pose.create(base[env_idx]))
        qpos = torch.as_tensor(rest, dtype=torch.float32).repeat(len(env_idx), 1)
        noisy = list(entry.noise_joints)  # the fingers stay open
        qpos[:, noisy] += noise * joint_noise[:, : len(noisy)]
        agent.reset(qpos)


def default_rest(entry: robots.Robot) -> np.ndarray:
    """The entry's rest joint positions, or its agent class's first keyframe's (the rest an
    env without ``robot_init_qpos`` starts from)."""
    if entry.rest_qpos is not None:
        return np.asarray(entry.rest_qpos, dtype=np.float64)
    keyframes = REGISTERED_AGENTS[entry.uid].agent_cls.keyframes
    return np.asarray(next(iter(keyframes.values())).qpos, dtype=np.float64)


def tcp_pose(agent, entry: robots.Robot):
    """The TCP's ManiSkill ``Pose`` (batched): the entry's link, or the agent's ``tcp_pose``;
    on the CPU simulation an entry with ``tcp_tips`` (the SO-100) is read from SAPIEN: its jaw
    tips' midpoint and its ``finger1_link``'s orientation, as the agent's property builds it
    from three ManiSkill link poses (0.3 ms; this 0.03 ms, the same values)."""
    if entry.tcp_link is not None:
        return agent.robot.links_map[entry.tcp_link].pose
    if entry.tcp_tips is None or agent.scene.gpu_sim_enabled:
        return agent.tcp_pose
    q = link_components(agent.finger1_link)[0].entity_pose.q
    return Pose.create_from_pq(
        torch.from_numpy(tcp_position_cpu(agent, entry)), torch.from_numpy(q[None])
    )


def tcp_position_cpu(agent, entry: robots.Robot) -> np.ndarray:
    """``(1, 3)``: the TCP position of the CPU simulation's one env, read from SAPIEN."""
    links = agent.robot.links_map
    if entry.tcp_link is not None:
        return np.array([link_components(links[entry.tcp_link])[0].entity_pose.p])
    if entry.tcp_tips is not None:  # float32 as the agent's tcp_pos computes it
        a, b = (link_components(links[name])[0].entity_pose.p for name in entry.tcp_tips)
        return ((a + b) / np.float32(2))[None]
    return agent.tcp_pose.p.cpu().numpy()


def is_grasping(agent, obj, entry: robots.Robot) -> torch.Tensor:
    """Per env (bool tensor): the agent grasps ``obj``, by the agent's own ``is_grasping``
    rule (its defaults): in one CPU pass (``envs/contacts.py``) where the entry states the rule,
    else by calling it."""
    if entry.grasp_check is not None:
        return contacts.is_grasping(agent, obj, entry.grasp_check)
    return agent.is_grasping(obj)
