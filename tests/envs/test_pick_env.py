from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import LAYOUTS, snapshot
from mani_skill.utils.structs.pose import Pose
from placement_checks import check_constraints

import embodied_envs  # noqa: F401
from embodied_envs.envs.observation import MAX_MOVERS, STATE_KEYS
from embodied_envs.layout import LayoutError, LayoutPose
from embodied_envs.paths import default_layout
from embodied_envs.robots import PANDA

REST_QPOS = np.array(PANDA.rest_qpos)

ENV_ID = "PickEmbodiedGen-v1"


@pytest.fixture(scope="module", params=LAYOUTS, ids=[p.stem for p in LAYOUTS])
def env(request):
    e = gym.make(ENV_ID, layout_file=str(request.param))
    yield e
    e.close()


def test_make_without_arguments_uses_default_layout():
    e = gym.make(ENV_ID)
    try:
        assert e.unwrapped.layout_file == default_layout()
        assert default_layout().is_relative_to(Path(embodied_envs.__file__).parent / "data")
        assert e.unwrapped.layouts[0].target_node == "can"
        from mani_skill.utils.registration import REGISTERED_ENVS

        assert REGISTERED_ENVS[ENV_ID].max_episode_steps == 500
    finally:
        e.close()


def test_reset_puts_everything_at_layout_poses_and_steps(env):
    obs, info = env.reset(seed=3, options=dict(reconfigure=True))
    u = env.unwrapped
    layout = u.layouts[0]
    table = u.env_actors["env0"][layout.context].pose.raw_pose[0].cpu().numpy()
    expected = layout.pose(layout.context).to_raw()
    np.testing.assert_allclose(table[:3], expected[:3], atol=1e-5)
    assert abs(abs(np.dot(table[3:], expected[3:])) - 1) < 1e-5
    # the objects start where this episode drew them: every placement rule holds
    poses = {}
    for node in layout.object_nodes():
        if node != layout.context:
            x, y, z, qw, qx, qy, qz = u.env_actors["env0"][node].pose.raw_pose[0].tolist()
            poses[node] = LayoutPose.from_layout([x, y, z - u.objs_z_offset, qx, qy, qz, qw])
    assert check_constraints(layout.with_poses(poses)) == []
    robot = layout.pose(layout.robot).raised(u.robot_z_offset).to_raw()
    np.testing.assert_allclose(
        u.agent.robot.pose.raw_pose[0].cpu().numpy()[:3], robot[:3], atol=1e-5
    )
    qpos = u.agent.robot.get_qpos()[0].cpu().numpy()
    assert np.all(np.abs(qpos[:7] - REST_QPOS[:7]) < 0.02 * 6)
    np.testing.assert_allclose(qpos[7:], [0.04, 0.04], atol=1e-6)
    # the graded object is this env's first manipulated object
    assert torch.equal(u.obj.pose.p, u.env_actors["env0"][layout.target_node].pose.p)
    goal = u.goal_site.pose.p[0].cpu().numpy()
    if u.tasks[0].kind == "pick":  # else the marker shows the first mover's destination
        top_z = float(u.layout_scene.top_z[0])
        low, high = u.goal_region.height  # the env's own limits, not literals
        assert top_z + low - 1e-5 <= goal[2] <= top_z + high + 1e-5
        d = np.linalg.norm(goal[:2] - robot[:2])
        near, far = u.goal_region.distance_band(u.placement_limits)
        assert near - 1e-5 <= d <= far + 1e-5
    else:
        np.testing.assert_allclose(goal, u.task_reader.dest[0, 0], atol=1e-5)
    for _ in range(20):
        obs, rew, term, trunc, info = env.step(env.action_space.sample())
    assert obs.shape == (1, env.observation_space.shape[-1])
    assert torch.isfinite(obs).all() and torch.isfinite(rew).all()
    for key in ("success", "is_obj_placed", "is_robot_static", "is_grasped"):
        assert info[key].dtype == torch.bool and info[key].shape == (1,)


def test_success_is_reachable_with_max_reward(env):
    env.reset(seed=1)
    u = env.unwrapped
    assert not u.evaluate()["success"].any()
    goal = u.goal_site.pose.p
    u.obj.set_pose(type(u.obj.pose).create_from_pq(goal, u.obj.pose.q))
    u.agent.robot.set_qvel(torch.zeros_like(u.agent.robot.get_qvel()))
    info = u.evaluate()
    assert info["is_obj_placed"].all() and info["is_robot_static"].all() and info["success"].all()
    r = u.compute_normalized_dense_reward(None, None, info)
    assert torch.allclose(r, torch.ones_like(r))
    # 3 cm off the goal is not placed
    u.obj.set_pose(type(u.obj.pose).create_from_pq(goal + torch.tensor([0.03, 0, 0]), u.obj.pose.q))
    assert not u.evaluate()["is_obj_placed"].any()


def test_reconfigure_with_same_seed_gives_same_layout(env):
    env.reset(seed=5, options=dict(reconfigure=True))
    first = env.unwrapped.layouts[0].position
    env.reset(seed=5, options=dict(reconfigure=True))
    assert env.unwrapped.layouts[0].position == first
    env.reset(seed=6, options=dict(reconfigure=True))
    assert env.unwrapped.layouts[0].position != first


def test_first_configuration_uses_the_file_poses():
    e = gym.make(ENV_ID, replace_objs=True)
    try:
        u = e.unwrapped
        assert u.layouts[0].position == u.base_layout.position
    finally:
        e.close()


def test_render_modes_and_visual_obs():
    e = gym.make(
        ENV_ID,
        obs_mode="rgbd",
        render_mode="all",
        replace_objs=False,
        camera_cfg=dict(image_hw=[96, 128]),
    )
    try:
        obs, _ = e.reset(seed=0)
        rgb = obs["sensor_data"]["base_camera"]["rgb"]
        assert rgb.shape == (1, 128, 128, 3) and rgb.dtype == torch.uint8
        assert obs["sensor_data"]["base_camera"]["depth"].shape == (1, 128, 128, 1)
        img = e.render()
        # render camera, base_camera rgb and its depth, tiled
        assert img.dtype == torch.uint8 and img.shape == (1, 128, 3 * 128, 3)
        u = e.unwrapped
        for mode, shape in (
            ("rgb_array", (1, 96, 128, 3)),
            ("sensors", (1, 128, 256, 3)),
            ("human", (1, 96, 128, 3)),
        ):
            u.render_mode = mode
            out = e.render()
            assert tuple(out.shape) == shape and out.dtype == torch.uint8, mode
        # the base camera sees the table top and the target object
        u.render_mode = "all"
        seg = u.scene.sensors["base_camera"]
        u._get_obs_sensor_data()  # as an observation: hidden objects hidden, then a picture
        ids = seg.get_obs(rgb=False, depth=False, segmentation=True)["segmentation"][0, ..., 0]
        layout = u.layouts[0]
        table_id = u.env_actors["env0"][layout.context].per_scene_id[0]
        obj_id = u.env_actors["env0"][layout.target_node].per_scene_id[0]
        assert (ids == table_id).float().mean() > 0.2
        assert (ids == obj_id).sum() > 10
        # the goal is shown in human renders and hidden from sensors
        goal_id = u.goal_site.per_scene_id[0]
        assert not (ids == goal_id).any()
        u.render_mode = "rgb_array"
        # on the render camera's line of sight, a third of the way from eye to target
        u.goal_site.set_pose(
            type(u.goal_site.pose).create_from_pq(torch.tensor([[0.6, 0, 1.0333]]))
        )
        cam = u.scene.human_render_cameras["render_camera"]
        for obj in u._hidden_objects:
            obj.show_visual()
        u.scene.update_render(update_sensors=False, update_human_render_cameras=True)
        cam.capture()
        human = cam.get_obs(rgb=True, segmentation=True, depth=False, position=False)
        goal = human["segmentation"][0, ..., 0] == goal_id
        assert goal.sum() > 20, "the goal sphere is in the render camera's view"
        rgb = e.render()[0][goal].int()  # pure green (0, 255, 0) lit: green dominates
        assert (rgb[:, 1] > rgb[:, 0] + 60).float().mean() > 0.9
        assert (rgb[:, 1] > rgb[:, 2] + 60).float().mean() > 0.9
    finally:
        e.close()


def test_state_dict_obs_mode_has_task_fields():
    e = gym.make(ENV_ID, obs_mode="state_dict", replace_objs=False)
    try:
        obs, _ = e.reset(seed=0)
        for key in (
            "tcp_pose",
            "goal_pos",
            "is_grasped",
            *STATE_KEYS,
        ):
            assert key in obs["extra"], key
        assert obs["extra"]["mover_pose"].shape == (1, 7 * MAX_MOVERS)
    finally:
        e.close()


def test_bad_arguments_fail_before_simulation(tmp_path, scene_copy):
    before = snapshot(scene_copy)
    with pytest.raises(ValueError, match="render_mode='video' is not supported"):
        gym.make(ENV_ID, render_mode="video")
    with pytest.raises(ValueError, match=r"image_hw=\[0, 256\] must be two positive integers"):
        gym.make(ENV_ID, camera_cfg=dict(image_hw=[0, 256]))
    layout = scene_copy / "layouts" / "default.json"
    layout.write_text(layout.read_text().replace('"franka"', '"ur5"'))
    before = snapshot(scene_copy)
    with pytest.raises(
        LayoutError, match=r'relation\["robot"\] is "ur5", which has no ManiSkill model here'
    ):
        gym.make(ENV_ID, layout_file=str(layout))
    e = gym.make(ENV_ID, layout_file=str(layout), robot_uids="panda")  # explicit robot works
    e.reset(seed=0)
    e.close()
    assert snapshot(scene_copy) == before  # nothing written beside the input


def test_object_knocked_off_the_table_rests_on_the_floor_and_fails(env):
    """The ground holds what falls; ``fail`` (and ManiSkill's ``terminated``) says so, and the
    next reset clears it."""
    u = env.unwrapped
    for seed in range(12):  # a fresh episode is never failed, wherever the objects start
        env.reset(seed=seed)
        assert not bool(u.evaluate()["fail"][0]), seed
    ls = u.layout_scene
    assert ls.floor_z == pytest.approx(0.0, abs=0.05)
    top = ls.episodes.top
    # push the target just beyond the edge of its table, on the side away from the robot
    centre = (top.lo[0] + top.hi[0]) / 2
    away = centre - u.agent.robot.pose.p[0, :2]
    away = away / torch.linalg.norm(away)
    reach = float(torch.linalg.norm(top.hi[0] - top.lo[0]))
    p = u.obj.pose.p.clone()
    p[0, :2] = centre + away * reach
    u.obj.set_pose(Pose.create_from_pq(p, u.obj.pose.q))
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    for _ in range(80):
        _, _, terminated, truncated, info = env.step(zero)
    z = float(u.obj.pose.p[0, 2])
    assert ls.floor_z - 0.01 < z < ls.floor_z + 0.15, f"the object rests on the floor, z={z}"
    assert bool(info["fail"][0]) and bool(terminated[0]) and not bool(info["success"][0])
    # a fall straight down beside the table: below the top by more than fail_drop
    assert z < float(ls.top_z[0]) - u.fail_drop
    env.reset(seed=0)
    info = u.evaluate()
    assert not bool(info["fail"][0])


def test_fail_is_the_table_footprint_and_height():
    """``off_table`` on points: inside the top and at its height is not off; below it by more
    than the drop, or outside its footprint at any height, is."""
    e = gym.make(ENV_ID)
    try:
        e.reset(seed=0)
        ls = e.unwrapped.layout_scene
        top = ls.episodes.top
        centre = (top.lo[0] + top.hi[0]) / 2
        z = float(ls.top_z[0])
        pts = torch.tensor(
            [
                [*centre.tolist(), z + 0.3],  # held above the table
                [*centre.tolist(), z - 0.04],  # sunk a little: not yet fallen
                [*centre.tolist(), z - 0.06],  # below the drop
                [float(top.hi[0, 0]) + 0.05, float(centre[1]), z + 0.01],  # beside the top
            ]
        )
        off = [bool(ls.off_table(p[None], 0.05)[0]) for p in pts]
        assert off == [False, False, True, True]
    finally:
        e.close()


def test_instructions_are_the_layouts_task_or_built_from_its_target(layout_dict):
    """One instruction per env: relation.task_desc; without it, the target's objs_desc; without
    that, the target's node name."""
    from embodied_envs.layout import LayoutInfo

    e = gym.make(ENV_ID)
    try:
        assert e.unwrapped.instructions == [layout_dict["relation"]["task_desc"]]
    finally:
        e.close()
    d = dict(layout_dict, relation={k: v for k, v in layout_dict["relation"].items()
                                     if k != "task_desc"})  # fmt: skip
    built = LayoutInfo.from_dict(d)
    assert built.instruction == "Pick up a blue soda can with a silver lid and hold it at the goal."
    built = LayoutInfo.from_dict({k: v for k, v in d.items() if k != "objs_desc"})
    assert built.instruction == "Pick up can and hold it at the goal."


def test_the_arm_is_static_by_its_displacement_over_the_control_step():
    """``is_robot_static`` and the reward's static term read each arm joint's displacement over
    the last control step over its duration (``TaskReader._arm_speed``), not the simulator's
    reported velocity: nothing moved the arm after a reset or a state set from outside; a
    step that turns the first joint reads that joint's move over 0.02 s."""
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(default_layout()),
                   control_mode="pd_joint_pos")  # fmt: skip
    try:
        env.reset(seed=0)
        u = env.unwrapped
        assert bool(u.evaluate()["is_robot_static"][0])
        q0 = u.agent.robot.get_qpos()[0].numpy().copy()
        action = np.r_[q0[:7] + np.array([0.3, 0, 0, 0, 0, 0, 0]), 1.0].astype(np.float32)
        info = env.step(action)[4]
        q1 = u.agent.robot.get_qpos()[0].numpy()
        speed = u._last_rules[0].arm_speed[0]
        np.testing.assert_allclose(speed, np.abs(q1 - q0)[:7] / u.control_timestep, atol=1e-4)
        assert speed[0] > 0.2 and not bool(info["is_robot_static"][0])
        u.set_state_dict(u.get_state_dict())
        assert bool(u.evaluate()["is_robot_static"][0])
    finally:
        env.close()
