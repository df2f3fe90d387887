"""Every robot of ``embodied_envs/robots.py`` whose model ships in ManiSkill's wheel works in
the env (make, reset, step in two control modes, obs, base pose, reach, gripper, grasp check);
the others, and names with no model, are refused in one line before anything is simulated."""

import inspect
import math

import gymnasium as gym
import numpy as np
import pytest
import torch

import embodied_envs  # noqa: F401
from embodied_envs import robots
from embodied_envs.cli.layout_cmds import validate_problems
from embodied_envs.config import resolve_robot
from embodied_envs.envs import agents
from embodied_envs.envs.observation import STATE_KEYS
from embodied_envs.layout import LayoutError

ENV_ID = "PickEmbodiedGen-v1"
WHEEL = ("panda", "panda_wristcam", "so100", "koch-v1.1", "fetch")
# state obs: qpos and qvel, then the extras: tcp_pose 7, goal_pos 3, is_grasped 1,
# task_kind 3, and the task's slots (envs/observation.py)
EXTRA_STATE = 7 + 3 + 1 + 3 + sum(STATE_KEYS.values())
DOF = {"panda": 9, "panda_wristcam": 9, "so100": 6, "koch-v1.1": 6, "fetch": 15}


def yaw(q_wxyz) -> float:
    w, x, y, z = (float(v) for v in q_wxyz)
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def gripper_sum(env) -> float:
    j = env.unwrapped.robot_entry.gripper.joints
    return float(env.unwrapped.agent.robot.get_qpos()[0, -j:].sum())


@pytest.fixture(scope="module", params=WHEEL)
def robot_env(request):
    e = gym.make(ENV_ID, robot_uids=request.param, obs_mode="state")
    yield request.param, e
    e.close()


def test_entries_are_the_wheel_and_download_arms():
    assert set(WHEEL) <= set(robots.ROBOTS)
    assert {u for u, r in robots.ROBOTS.items() if not r.in_wheel} == {
        "xarm6_robotiq", "widowxai", "widowx250s",
    }  # fmt: skip
    for uid in WHEEL:
        r = robots.ROBOTS[uid]
        assert len(r.rest_qpos) == DOF[uid] and len(r.noise_joints) <= 7
        lo, hi = r.reach
        assert 0 <= lo < hi and r.goal_inset * 2 < hi - lo  # a goal band is left


def test_robot_resets_reproducibly_and_stands_at_the_layouts_spot(robot_env):
    uid, env = robot_env
    u, entry = env.unwrapped, robots.ROBOTS[uid]
    assert u.agent.uid == uid
    obs, _ = env.reset(seed=4)
    again, _ = env.reset(seed=4)
    assert obs.shape == (1, 2 * DOF[uid] + EXTRA_STATE)
    assert torch.isfinite(obs).all() and torch.equal(obs, again)
    # the base: the layout's spot moved back by edge_offset, turned by base_yaw, on the
    # table top, or on the floor (Fetch)
    spot = u.layout_scene.robot_poses[0].cpu().numpy()
    base = u.agent.robot.pose.raw_pose[0].cpu().numpy()
    heading = yaw(spot[3:])
    back = entry.edge_offset * np.array([math.cos(heading), math.sin(heading)])
    np.testing.assert_allclose(base[:2], spot[:2] - back, atol=1e-5)
    z = float(u.layout_scene.floor_z) if entry.base_height == "floor" else spot[2]
    assert base[2] == pytest.approx(z, abs=1e-5)
    turn = (yaw(base[3:]) - heading - entry.base_yaw + math.pi) % (2 * math.pi) - math.pi
    assert abs(turn) < 1e-5
    if uid.startswith("panda"):  # the Panda stands exactly on the layout's robot pose
        np.testing.assert_allclose(base, spot, atol=1e-6)
    # the arm starts at its rest joints (plus the default 0.02 rad noise), facing the table:
    # its TCP lies ahead of the spot, and the target within the robot's reach of it
    qpos = u.agent.robot.get_qpos()[0].cpu().numpy()
    assert np.abs(qpos - agents.default_rest(entry)).max() < 0.02 * 6
    ahead = np.array([math.cos(heading), math.sin(heading)])
    tcp = agents.tcp_pose(u.agent, entry).p[0].cpu().numpy()
    assert float((tcp[:2] - spot[:2]) @ ahead) > 0.05
    # the task's every-step CPU read of it (from SAPIEN; the SO-100's its jaw tips' midpoint)
    np.testing.assert_array_equal(agents.tcp_position_cpu(u.agent, entry)[0], tcp)
    # and the whole pose the observation reads is the agent's, bit for bit
    theirs = u.agent.robot.links_map[entry.tcp_link].pose if entry.tcp_link else u.agent.tcp_pose
    mine = agents.tcp_pose(u.agent, entry).raw_pose
    assert mine.dtype == theirs.raw_pose.dtype and mine.shape == theirs.raw_pose.shape
    np.testing.assert_array_equal(mine.numpy(), theirs.raw_pose.numpy())
    target = u.obj.pose.p[0].cpu().numpy()
    centre = spot[:2] + entry.reach_origin * ahead  # its pan axis (the Panda's: the spot)
    assert entry.reach[0] < np.linalg.norm(target[:2] - centre) < entry.reach[1]
    assert u.placement_limits.reach_origin == entry.reach_origin
    assert (u.placement_limits.reach_min, u.placement_limits.reach_max) == entry.reach
    assert (u.goal_region.inset, tuple(u.goal_region.height)) == (
        entry.goal_inset, tuple(entry.goal_height),
    )  # fmt: skip


def test_gripper_closes_by_its_entry_and_grasp_is_the_agents(robot_env):
    uid, env = robot_env
    u, grip = env.unwrapped, robots.ROBOTS[uid].gripper
    env.reset(seed=0)
    opened = gripper_sum(env)
    assert opened == pytest.approx(grip.joints * grip.open_qpos, abs=1e-3)
    # the opening fraction's scale (tasks' "released"): summed joints shut and open
    assert u.task_scene.finger_span == pytest.approx(grip.span)
    action = torch.zeros(env.action_space.shape)
    action[grip.action_index] = grip.action_closed
    for _ in range(20):  # a "delta" gripper steps by its controller's limit per step
        obs, reward, term, trunc, info = env.step(action)
        assert torch.isfinite(obs).all() and torch.isfinite(reward).all()
    closed = gripper_sum(env)
    # the fingers moved toward shut: an absolute command by a third of their span in 0.8 s; a
    # delta one (SO-100, Koch) steadily, the Koch's weak jaw PD slowest (0.11 rad of 1.6)
    lo, hi = grip.span
    least = 1 / 3 if grip.action_kind == "absolute" else 0.05
    assert (opened - closed) / (hi - lo) > least, (opened, closed)
    assert set(info) >= {"success", "fail", "is_grasped"} and not bool(info["is_grasped"])
    # the entry's grasp rule is the agent's is_grasping with its defaults (checked step by step
    # against it in tests/envs/test_contacts.py)
    defaults = inspect.signature(type(u.agent).is_grasping).parameters
    rule = robots.ROBOTS[uid].grasp_check
    assert (rule.min_force, rule.max_angle) == (
        defaults["min_force"].default, defaults["max_angle"].default,
    )  # fmt: skip


@pytest.mark.parametrize("uid", WHEEL)
def test_joint_position_control_holds_and_brings_the_tcp_over_the_target(uid):
    env = gym.make(ENV_ID, robot_uids=uid, obs_mode="state", control_mode="pd_joint_pos",
                   robot_init_qpos_noise=0.0)  # fmt: skip
    try:
        u, entry = env.unwrapped, robots.ROBOTS[uid]
        assert "pd_joint_pos" in u.agent.supported_control_modes
        env.reset(seed=1)
        start = u.agent.robot.get_qpos()[0].clone()
        action = torch.as_tensor(_hold_action(u), dtype=torch.float32)
        for _ in range(4):
            env.step(action)
        moved = (u.agent.robot.get_qpos()[0] - start).abs()
        assert float(moved.max()) < 0.05, moved
        # joints that put the TCP 15 cm over the target (a search on the arm's kinematics),
        # then commanded: the arm stands where it reaches the table's objects
        above = u.obj.pose.p[0].cpu().numpy() + np.array([0.0, 0.0, 0.15])
        goal_q = _joints_reaching(u, entry, above)
        for _ in range(40):
            env.step(torch.as_tensor(_hold_action(u, goal_q), dtype=torch.float32))
        tcp = agents.tcp_pose(u.agent, entry).p[0].cpu().numpy()
        assert np.linalg.norm(tcp - above) < 0.05, (tcp, above)
    finally:
        env.close()


def _joints_reaching(u, entry, point, rounds: int = 6, draws: int = 150) -> np.ndarray:
    """Joint positions (arm joints searched, the others as now) whose TCP lies nearest
    ``point``: random draws within the joint limits, narrowed round by round around the best
    (the robot's joints are put back afterwards)."""
    robot, rng = u.agent.robot, np.random.default_rng(0)
    now = robot.get_qpos()[0].cpu().numpy()
    arm = list(entry.noise_joints)
    lim = np.clip(robot.get_qlimits()[0].cpu().numpy()[arm], -np.pi, np.pi)
    best, best_d, width = now.copy(), np.inf, lim[:, 1] - lim[:, 0]
    for _ in range(rounds):
        centre = best[arm]
        for _ in range(draws):
            q = best.copy()
            q[arm] = np.clip(centre + rng.uniform(-0.5, 0.5, len(arm)) * width, *lim.T)
            robot.set_qpos(torch.as_tensor(q[None], dtype=torch.float32))
            d = np.linalg.norm(agents.tcp_pose(u.agent, entry).p[0].cpu().numpy() - point)
            if d < best_d:
                best, best_d = q, d
        width = width / 3
    robot.set_qpos(torch.as_tensor(now[None], dtype=torch.float32))
    assert best_d < 0.02, f"no joints put the TCP within 2 cm of {point} ({best_d:.3f} m)"
    return best


def _hold_action(u, qpos: np.ndarray | None = None) -> np.ndarray:
    """The pd_joint_pos action that holds the joints at ``qpos`` (default: where they are):
    each controller's joints' positions (gripper controllers: their normalised open
    command; delta and velocity controllers: zero)."""
    if qpos is None:
        qpos = u.agent.robot.get_qpos()[0].cpu().numpy()
    parts = []
    combined = u.agent.controller  # one controller per body part, or one for every joint
    for name, ctrl in getattr(combined, "controllers", {"arm": combined}).items():
        idx = [u.agent.robot.active_joints.index(j) for j in ctrl.joints]
        if "gripper" in name:
            parts.append(np.ones(ctrl.action_space.shape))  # open, as it starts
        elif getattr(ctrl.config, "use_delta", True):  # deltas, Fetch's base velocity
            parts.append(np.zeros(ctrl.action_space.shape))
        else:
            parts.append(qpos[idx])
    return np.concatenate(parts)


@pytest.mark.parametrize("uid", ("so100", "koch-v1.1", "fetch"))
def test_visual_obs_and_hybrid_frames(uid):
    env = gym.make(ENV_ID, robot_uids=uid, obs_mode="rgbd", render_mode="hybrid")
    try:
        obs, _ = env.reset(seed=0)
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        assert tuple(rgb.shape) == (1, 128, 128, 3)
        assert tuple(obs["sensor_data"]["base_camera"]["depth"].shape) == (1, 128, 128, 1)
        assert float(rgb.float().std()) > 1.0  # not a blank image: the camera sees the scene
        frame = env.render()
        assert frame.shape[-1] == 3 and float(frame.float().std()) > 1.0
    finally:
        env.close()


def test_pointcloud_obs_of_a_small_arm():
    env = gym.make(ENV_ID, robot_uids="so100", obs_mode="pointcloud")
    try:
        obs, _ = env.reset(seed=0)
        xyz = obs["pointcloud"]["xyzw"]
        assert xyz.shape[0] == 1 and xyz.shape[-1] == 4 and torch.isfinite(xyz).all()
    finally:
        env.close()


def test_user_limits_win_field_by_field():
    env = gym.make(ENV_ID, robot_uids="so100", placement_limits=dict(reach_max=0.28),
                   goal_region=dict(inset=0.04))  # fmt: skip
    try:
        u = env.unwrapped
        lo = robots.robot("so100").reach[0]  # the robot's, under the user's reach_max
        assert (u.placement_limits.reach_min, u.placement_limits.reach_max) == (lo, 0.28)
        assert (u.goal_region.inset, tuple(u.goal_region.height)) == (0.04, (0.04, 0.10))
    finally:
        env.close()


def test_a_download_arm_is_refused_when_absent_and_passes_when_present(monkeypatch, tmp_path):
    cls = agents.REGISTERED_AGENTS["xarm6_robotiq"].agent_cls
    monkeypatch.setattr(cls, "urdf_path", str(tmp_path / "robots/xarm6/xarm6_robotiq.urdf"))
    with pytest.raises(ValueError) as err:
        gym.make(ENV_ID, robot_uids="xarm6_robotiq")
    line = str(err.value)
    assert "\n" not in line and "robot_uids='xarm6_robotiq'" in line
    assert "is not on this machine" in line
    assert "`python -m mani_skill.utils.download_asset xarm6_robotiq`" in line
    model = tmp_path / "robots/xarm6/xarm6_robotiq.urdf"
    model.parent.mkdir(parents=True)
    model.write_text("<robot name='xarm6'/>")
    agents.check_robot("xarm6_robotiq")  # present: accepted like the wheel's arms


@pytest.mark.parametrize(
    ("uid", "expected"),
    [
        ("ur_10e", "robot_uids='ur_10e': ManiSkill's ur_10e has no gripper"),
        ("panda_stick", "robot_uids='panda_stick': ManiSkill's panda_stick has no gripper"),
        ("robot9000", "robot_uids='robot9000' is not a ManiSkill robot uid; use one of ['panda'"),
        (("panda", "panda", "panda"), "PickEmbodiedGen-v1 loads one robot or two"),
        (("panda", "ur_10e"), "robot_uids='ur_10e': ManiSkill's ur_10e has no gripper"),
    ],
)
def test_robots_the_env_cannot_take_are_refused_in_one_line(uid, expected):
    with pytest.raises(ValueError) as err:
        gym.make(ENV_ID, robot_uids=uid)
    assert expected in str(err.value) and "\n" not in str(err.value)


def test_layout_robot_names(scene_copy):
    assert resolve_robot("franka", None, "f.json") == "panda"
    assert resolve_robot("Franka Panda", None, "f.json") == "panda"
    assert resolve_robot("so100", None, "f.json") == "so100"
    assert resolve_robot("ur5", "koch-v1.1", "f.json") == "koch-v1.1"  # the keyword wins
    # the robot node, named as EmbodiedGen's generator names it (relation and position)
    path = scene_copy / "layouts" / "default.json"
    path.write_text(path.read_text().replace('"franka"', '"ur5"'))
    with pytest.raises(LayoutError) as err:
        gym.make(ENV_ID, layout_file=str(path))
    line = str(err.value)
    assert line.startswith(str(path)) and '"ur5", which has no ManiSkill model here' in line
    assert "'so100'" in line and 'Fix: pass robot_uids="<one of them>"' in line
    problems = validate_problems(path, check_placement=False)
    assert any('relation["robot"] is "ur5"' in p for p in problems), problems


def test_the_expert_refuses_an_arm_it_cannot_drive_in_one_line():
    from embodied_envs.solvers.pick_place import PickPlaceSolver

    env = gym.make(ENV_ID, robot_uids="fetch", control_mode="pd_joint_pos")
    try:
        with pytest.raises(ValueError) as err:
            PickPlaceSolver(env)
        line = str(err.value)
        assert line.startswith("robot_uids='fetch': the scripted expert drives only ")
        assert "['panda', 'panda_wristcam', 'so100', 'koch-v1.1']" in line and "\n" not in line
    finally:
        env.close()


def test_state_dict_obs_of_a_small_arm():
    env = gym.make(ENV_ID, robot_uids="koch-v1.1", obs_mode="state_dict")
    try:
        obs, _ = env.reset(seed=0)
        assert tuple(obs["agent"]["qpos"].shape) == (1, 6)
        tcp = obs["extra"]["tcp_pose"]  # the Koch's gripper_tcp link, its entry's TCP
        link = env.unwrapped.agent.robot.links_map["gripper_tcp"].pose.raw_pose
        torch.testing.assert_close(tcp, link)
    finally:
        env.close()


def test_a_layout_naming_a_small_arm_validates_with_its_reach(scene_copy):
    path = scene_copy / "layouts" / "default.json"
    path.write_text(path.read_text().replace('"franka"', '"so100"'))
    assert validate_problems(path) == []
    env = gym.make(ENV_ID, layout_file=str(path), obs_mode="state")
    try:
        assert env.unwrapped.agent.uid == "so100"
        assert env.unwrapped.placement_limits.reach_max == robots.ROBOTS["so100"].reach[1]
    finally:
        env.close()


def test_two_arms_stand_across_the_table_and_step_with_a_dict_action():
    from embodied_envs.solvers.pick_place import PickPlaceSolver

    env = gym.make(ENV_ID, robot_uids=["panda", "so100"], obs_mode="state")
    try:
        u = env.unwrapped
        obs, _ = env.reset(seed=2)
        assert obs.shape == (1, 2 * 9 + 2 * 6 + EXTRA_STATE) and torch.isfinite(obs).all()
        first, second = u.agent.agents
        assert (first.uid, second.uid) == ("panda", "so100")
        spot = u.layout_scene.robot_poses[0].cpu().numpy()
        np.testing.assert_allclose(first.robot.pose.raw_pose[0].cpu().numpy(), spot, atol=1e-6)
        # the second across the table's centre, facing back toward the first
        other = second.robot.pose.raw_pose[0].cpu().numpy()
        gap = spot[:2] - other[:2]
        assert np.linalg.norm(gap) > 0.8 and other[2] == pytest.approx(spot[2], abs=1e-5)
        facing = yaw(other[3:]) - robots.ROBOTS["so100"].base_yaw
        assert np.dot([math.cos(facing), math.sin(facing)], gap / np.linalg.norm(gap)) > 0.9
        action = {k: torch.zeros(s.shape) for k, s in env.action_space.spaces.items()}
        assert set(action) == {"panda-0", "so100-1"}
        for _ in range(3):
            obs, reward, *_, info = env.step(action)
        assert torch.isfinite(obs).all() and not bool(info["is_grasped"])
        with pytest.raises(ValueError, match=r"several robots take a dict of actions, one per "
                           r"agent: keys \['panda-0', 'so100-1'\]"):  # fmt: skip
            env.step(torch.zeros(14))
        with pytest.raises(ValueError, match="the scripted expert drives one arm"):
            PickPlaceSolver(env)
    finally:
        env.close()
