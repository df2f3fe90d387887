"""Hybrid rendering: simulated foreground over the splat background (foreground ids, depth
test, cached backgrounds)."""

import json
import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import DEFAULT_LAYOUT, snapshot

import embodied_envs  # noqa: F401
from embodied_envs.layout.pose import LayoutPose, quat_multiply_xyzw
from embodied_envs.splat import (
    GaussianSplat,
    PinholeCamera,
    SplatFileError,
    pose_splat,
    read_ply,
    render,
    write_ply,
)
from embodied_envs.splat.sh import SH_C0

ENV_ID = "PickEmbodiedGen-v1"
MAGENTA = (1.0, 0.0, 1.0)


def make(layout=DEFAULT_LAYOUT, **kw):
    kw.setdefault("obs_mode", "rgb")
    kw.setdefault("render_mode", "hybrid")
    return gym.make(ENV_ID, layout_file=str(layout), **kw)


@pytest.fixture(scope="module")
def env():
    e = make(hybrid_obs=True)
    e.reset(seed=0)
    yield e
    e.close()


def camera_data(u, name="render_camera"):
    """Raw simulated colour, segmentation and depth of a human camera in the current state."""
    cam = u.scene.human_render_cameras[name]
    for obj in u._hidden_objects:
        obj.show_visual()
    u.scene.update_render(update_sensors=False, update_human_render_cameras=True)
    cam.capture()
    data = cam.get_obs(rgb=True, depth=True, segmentation=True, position=False)
    return cam, data


def foreground_ids(u, env_idx=0, hidden=True):
    ids = [int(link.per_scene_id[env_idx]) for link in u.agent.robot.links]
    ids += [int(a.per_scene_id[0]) for a in u.env_actors[f"env{env_idx}"].values()]
    if hidden:
        ids.append(int(u.goal_site.per_scene_id[env_idx]))
    return ids


def independent_background(u, cam):
    """The splat render the background should be, posed here from env 0's layout."""
    layout = u.layouts[0]
    pose = layout.pose(layout.background)
    q = quat_multiply_xyzw(pose.q_xyzw, (0.7071, 0.0, 0.0, 0.7071))
    splat = pose_splat(
        read_ply(layout.gs_model_path()), torch.tensor(pose.p), torch.tensor(q[[3, 0, 1, 2]])
    )
    c = PinholeCamera.from_opengl(
        cam.camera.get_model_matrix()[0].numpy(),
        cam.camera.get_intrinsic_matrix()[0].numpy(),
        256,
        256,
    )
    return render(splat, c, backend="torch")


def test_foreground_is_the_simulated_render_and_background_the_splat(env):
    u = env.unwrapped
    hybrid = env.render()
    assert hybrid.shape == (1, 256, 256, 3) and hybrid.dtype == torch.uint8
    cam, data = camera_data(u)
    seg, depth = data["segmentation"][0, ..., 0], data["depth"][0, ..., 0].float() / 1000.0
    bg = independent_background(u, cam)
    fg = torch.isin(seg, torch.tensor(foreground_ids(u), dtype=seg.dtype))
    fg &= depth <= bg.surface_depth(0.5)
    assert 0.1 < fg.float().mean() < 0.9, "the view should hold both robot/table and room"
    rgb_array = u.render_simulated()[0]  # the plain render of the same state
    assert torch.equal(rgb_array, data["rgb"][0])
    assert torch.equal(hybrid[0][fg], rgb_array[fg])
    # the background is the splat posed by the layout (rendered here by posing the splat; the
    # env moves the camera instead, which differs by float rounding: at most 1 level, rarely)
    diff = (hybrid[0][~fg].int() - bg.rgb_uint8()[~fg].int()).abs()
    assert diff.max() <= 1 and (diff > 0).float().mean() < 1e-3
    # the room is drawn: background pixels are not the simulator's empty black
    assert hybrid[0][~fg].float().mean() > 60


def sensor_view(u):
    """The base camera's observation rgb, its raw simulated rgb, its sensor foreground (robot
    and layout actors nearer than the splat; sensors do not see the goal marker) and the
    splat background rendered independently of the env's cache."""
    rgb = u.get_obs()["sensor_data"]["base_camera"]["rgb"][0]
    raw, fg, bg, _ = base_camera_truth(u)
    return rgb, raw["rgb"][0], fg, bg.rgb_uint8()


def test_sensor_rgb_is_composited_like_the_human_view(env):
    rgb, raw, fg, bg = sensor_view(env.unwrapped)
    assert 0.05 < fg.float().mean() < 0.95
    assert torch.equal(rgb[fg], raw[fg])
    assert torch.equal(rgb[~fg], bg[~fg])


@pytest.mark.parametrize(
    "render_mode, hybrid_obs", [(None, True), ("rgb_array", True), ("hybrid", False)]
)
def test_hybrid_obs_is_its_own_switch(render_mode, hybrid_obs):
    """hybrid_obs composites the sensor observations whatever render_mode is; render_mode
    "hybrid" alone composites render() only."""
    e = make(render_mode=render_mode, hybrid_obs=hybrid_obs, replace_objs=False)
    try:
        e.reset(seed=0)
        u = e.unwrapped
        rgb, raw, fg, bg = sensor_view(u)
        assert torch.equal(rgb[fg], raw[fg]), "foreground pixels are the simulator's"
        if hybrid_obs:
            assert torch.equal(rgb[~fg], bg[~fg])
            assert (rgb[~fg] != raw[~fg]).any(-1).float().mean() > 0.5
        else:
            assert torch.equal(rgb, raw)
        if render_mode == "hybrid":
            frame = e.render()[0]
            assert (frame != u.render_simulated()[0]).any(-1).float().mean() > 0.2
    finally:
        e.close()


def test_background_is_rendered_once_per_camera_and_configuration(env):
    u = env.unwrapped
    env.reset(seed=4, options=dict(reconfigure=True))
    # pre-rendered at (re)configuration, before any frame is asked for
    cached = u.hybrid.cached("render_camera")
    assert cached is not None and cached.valid.all()
    assert u.hybrid.poses[0] == u.layouts[0].pose(u.layouts[0].background)
    before = u.hybrid.renders
    for _ in range(3):
        env.step(env.action_space.sample())
        env.render()
    assert u.hybrid.renders == before
    env.reset()  # a new episode keeps the configuration and its backgrounds
    env.render()
    assert u.hybrid.renders == before


def occluder_splat() -> GaussianSplat:
    """An opaque magenta wall at world x = 0.5 (between render camera and table), stored Y-up
    for an identity background pose: world (x, y, z) = file (x, -z, y) after +90 deg about X."""
    ys, zs = np.meshgrid(np.linspace(-0.15, 0.15, 61), np.linspace(0.95, 1.15, 41))
    n = ys.size
    world = np.stack([np.full(n, 0.5), ys.ravel(), zs.ravel()], 1)
    file = np.stack([world[:, 0], world[:, 2], -world[:, 1]], 1)

    def t(a):
        return torch.as_tensor(np.asarray(a), dtype=torch.float32)

    return GaussianSplat(
        means=t(file),
        quats_wxyz=t(np.tile([1.0, 0, 0, 0], (n, 1))),
        log_scales=t(np.tile(np.log([0.002, 0.006, 0.006]), (n, 1))),
        opacity_logits=t(np.full(n, 6.0)),
        sh=t(((np.array(MAGENTA) - 0.5) / SH_C0)[None, None].repeat(n, 0)),
    )


def test_depth_test_hides_objects_behind_a_splat_occluder(scene_copy):
    layout_file = scene_copy / "layouts" / "default.json"
    data = json.loads(layout_file.read_text())
    data["position"]["background"] = [0, 0, 0, 0, 0, 0, 1]
    layout_file.write_text(json.dumps(data))
    write_ply(occluder_splat(), scene_copy / "assets" / "background" / "gs_model.ply")
    images = {}
    for depth_test in (True, False):
        e = make(
            layout_file,
            hybrid_depth_test=depth_test,
            replace_objs=False,
            camera_cfg=dict(camera_eye=[0.9, 0.0, 1.1], camera_target_pt=[0.0, 0.0, 0.9]),
        )
        e.reset(seed=0)  # a fixed camera: the wall stands between it and the table
        images[depth_test] = e.render()[0]
        cam, raw = camera_data(e.unwrapped)
        wall = independent_background(e.unwrapped, cam)
        fg = torch.isin(
            raw["segmentation"][0, ..., 0],
            torch.tensor(foreground_ids(e.unwrapped), dtype=torch.int16),
        )
        e.close()
    covered = wall.alpha >= 0.5
    hidden = covered & fg
    assert hidden.float().mean() > 0.05, "the wall should cover part of the simulated scene"
    magenta = torch.tensor([255, 0, 255], dtype=torch.uint8)
    with_test, without = images[True], images[False]
    assert torch.equal(with_test[hidden], wall.rgb_uint8()[hidden])
    solid = hidden & (wall.alpha > 0.99)
    assert solid.float().mean() > 0.03
    assert ((with_test[solid].int() - magenta.int()).abs() <= 3).all()
    assert torch.equal(without[hidden], raw["rgb"][0][hidden])


def test_background_yaw_changes_the_background_image(scene_copy):
    layout_file = scene_copy / "layouts" / "default.json"
    data = json.loads(layout_file.read_text())
    x, y, z, qx, qy, qz, qw = data["position"]["background"]
    turn = quat_multiply_xyzw(
        [0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)], [qx, qy, qz, qw]
    )
    data["position"]["background"] = [x, y, z, *turn.tolist()]
    layout_file.write_text(json.dumps(data))
    e = make(layout_file, replace_objs=False)
    e.reset(seed=0)
    e.render()
    hybrid = e.unwrapped.hybrid
    turned = hybrid.cached("render_camera")
    assert hybrid.poses[0] == LayoutPose.from_layout(data["position"]["background"])
    # the same camera with the shipped yaw
    camera = PinholeCamera.from_opengl(
        turned.model[0].numpy(), turned.intrinsic[0].numpy(), 256, 256
    )
    original, _ = hybrid.render_one(camera, LayoutPose.from_layout([x, y, z, qx, qy, qz, qw]))
    e.close()
    diff = (turned.rgb[0].float() - original.float()).abs().mean()
    assert diff > 10, f"mean abs difference {diff:.1f} should show a turned room"


def test_missing_background_splat_fails_at_construction(scene_copy):
    (scene_copy / "assets" / "background" / "gs_model.ply").unlink()
    before = snapshot(scene_copy)
    layout_file = scene_copy / "layouts" / "default.json"
    with pytest.raises(SplatFileError) as e:
        make(layout_file)
    msg = str(e.value)
    assert "gs_model.ply" in msg and 'render_mode="hybrid"' in msg and str(layout_file) in msg
    assert "embodied-envs splat from-mesh MESH --out gs_model.ply" in msg
    assert snapshot(scene_copy) == before


def test_compositing_is_per_env_with_its_own_ids_background_and_depth(tmp_path):
    """Several envs at once (as on the GPU sim), without a simulator."""
    from embodied_envs.envs.hybrid import HybridRenderer
    from embodied_envs.splat.camera import GL_TO_CV

    write_ply(occluder_splat(), tmp_path / "gs_model.ply")
    room = tmp_path / "gs_model.ply"
    hybrid = HybridRenderer({room: "test"}, (0.7071, 0.0, 0.0, 0.7071))
    cam = PinholeCamera.look_at((0.9, 0.0, 1.05), (0.0, 0.0, 1.05), width=32, height=24)
    model = torch.tensor(np.linalg.inv(cam.world_to_cam) @ GL_TO_CV).expand(2, 4, 4)
    intrinsic = torch.tensor(cam.intrinsic).expand(2, 3, 3)
    moved = LayoutPose.from_xyz_yaw((0.0, 5.0, 0.0), 0.0)  # env 1: the wall is out of view
    poses = [LayoutPose.from_xyz_yaw((0.0, 0.0, 0.0), 0.0), moved]
    rgb = torch.full((2, 24, 32, 3), 77, dtype=torch.uint8)
    seg = torch.zeros((2, 24, 32, 1), dtype=torch.int16)
    seg[:, :, :16] = 5  # left half: id 5, right half: id 7, in both envs
    seg[:, :, 16:] = 7
    depth_mm = torch.full((2, 24, 32, 1), 1500, dtype=torch.int16)  # 1.5 m: behind the wall
    hybrid.configure(
        torch.tensor([[5], [7]]), torch.zeros((2, 0), dtype=torch.long), poses, [room, room]
    )
    images = dict(rgb=rgb, segmentation=seg, depth=depth_mm, position=torch.zeros((2, 24, 32, 3)))
    full = hybrid.composite("cam", images, model, intrinsic, human=False)
    out = full["rgb"]
    cached = hybrid.cached("cam")
    wall = type(cached)(cached.model[0], cached.intrinsic[0], cached.rgb[0], cached.depth[0], None)
    assert (wall.depth < 0.5).any() and torch.isinf(cached.depth[1]).all()
    covered = torch.isfinite(wall.depth)
    # env 0: only id 5 is foreground, and where the wall is nearer it hides it
    left = torch.zeros((24, 32), dtype=torch.bool)
    left[:, :16] = True
    shown0 = left & ~covered
    assert (out[0][shown0] == 77).all()
    assert torch.equal(out[0][~shown0], wall.rgb[~shown0])
    # env 1: only id 7 is foreground; its (empty) background is black
    assert (out[1][~left] == 77).all() and (out[1][left] == 0).all()
    # one mask for every texture: where the splat shows, its depth, points and id 0
    depth0, seg0, pos0 = (full[k][0] for k in ("depth", "segmentation", "position"))
    assert (depth0[shown0] == 1500).all() and (seg0[shown0] == 5).all()
    wall_mm = (wall.depth * 1000).round()
    assert torch.equal(depth0[covered][:, 0], wall_mm[covered].to(torch.int16))
    assert (seg0[~shown0] == 0).all() and (depth0[~shown0 & ~covered] == 0).all()
    assert torch.equal(full["splat_points"][0], covered & ~shown0)
    # the points lie on the camera rays of their pixels at the splat's depth (OpenGL frame)
    v, u = torch.nonzero(covered, as_tuple=True)
    z = -pos0[v, u, 2]
    assert torch.allclose(z, wall_mm[v, u], atol=0.5)
    px = pos0[v, u, 0] / z * cam.fx + cam.cx
    py = -pos0[v, u, 1] / z * cam.fy + cam.cy
    assert torch.allclose(px, u + 0.5, atol=0.05) and torch.allclose(py, v + 0.5, atol=0.05)
    assert (full["depth"][1] == torch.where(left[..., None], 0, 1500)).all()
    # the depth test is what hides env 0's pixels behind the wall
    hybrid.depth_test = False
    out = hybrid.composite("cam", images, model, intrinsic, human=False)["rgb"]
    assert (out[0][left] == 77).all()
    assert hybrid.renders == 2, "one background per env, rendered once"


def test_backgrounds_of_many_envs_in_batched_calls_equal_the_posed_splat(monkeypatch):
    """Every env's background from batched calls (three envs, calls of two) is the splat
    posed by that env's layout pose, as rendered by posing the splat itself."""
    from embodied_envs.config import SPLAT_Y_UP_TO_Z_UP
    from embodied_envs.envs import hybrid as hybrid_module
    from embodied_envs.layout import load_layout

    monkeypatch.setattr(hybrid_module, "MAX_CAMERAS_PER_CALL", 2)
    path = load_layout(DEFAULT_LAYOUT).gs_model_path()
    renderer = hybrid_module.HybridRenderer({path: DEFAULT_LAYOUT}, SPLAT_Y_UP_TO_Z_UP)
    cams = [
        PinholeCamera.look_at((0.6 * math.cos(a), 0.6 * math.sin(a), 1.1), (0, 0, 0.9), (0, 0, 1),
                              48, 40)
        for a in (0.0, 2.0, 4.0)
    ]  # fmt: skip
    poses = [LayoutPose.from_xyz_yaw((0.1 * k, 0.0, 0.0), 0.7 * k) for k in range(3)]
    rgb, depth = renderer.render_backgrounds(cams, poses, [path] * 3)
    assert rgb.shape == (3, 40, 48, 3) and depth.shape == (3, 40, 48)
    assert renderer.renders == 3
    stored = read_ply(path)
    for k, (cam, pose) in enumerate(zip(cams, poses, strict=True)):
        q = quat_multiply_xyzw(pose.q_xyzw, SPLAT_Y_UP_TO_Z_UP)
        posed = pose_splat(stored, torch.tensor(pose.p), torch.tensor(q[[3, 0, 1, 2]]))
        want = render(posed, cam, backend="torch")
        diff = (rgb[k].int() - want.rgb_uint8().int()).abs()
        assert diff.max() <= 1 and (diff > 0).float().mean() < 1e-3, k
        assert want.alpha.mean() > 0.5  # the room fills the view
    assert not torch.equal(rgb[0], rgb[1])  # each env its own view


def base_camera_truth(u):
    """The base camera's raw simulated textures (with position), its sensor foreground and the
    independently rendered splat (of env 0), and the camera."""
    sensor = u.scene.sensors["base_camera"]
    raw = sensor.get_obs(rgb=True, depth=True, segmentation=True, position=True)
    seg = raw["segmentation"][0, ..., 0]
    fg = torch.isin(seg, torch.tensor(foreground_ids(u, hidden=False), dtype=seg.dtype))
    cam = PinholeCamera.from_opengl(
        sensor.camera.get_model_matrix()[0].numpy(),
        sensor.camera.get_intrinsic_matrix()[0].numpy(),
        128,
        128,
    )
    layout = u.layouts[0]
    pose = layout.pose(layout.background)
    q = quat_multiply_xyzw(pose.q_xyzw, (0.7071, 0.0, 0.0, 0.7071))
    splat = pose_splat(
        read_ply(layout.gs_model_path()), torch.tensor(pose.p), torch.tensor(q[[3, 0, 1, 2]])
    )
    bg = render(splat, cam, backend="torch")
    fg &= raw["depth"][0, ..., 0].float() / 1000.0 <= bg.surface_depth(0.5)
    return raw, fg, bg, cam


@pytest.mark.parametrize("obs_mode", ["rgbd", "rgb+depth+segmentation", "pointcloud"])
def test_hybrid_depth_points_and_segmentation_agree_with_the_splat(obs_mode):
    """With hybrid_obs, every texture follows one mask: the simulator's values where it shows,
    the splat's surface (depth, points at that depth on the pixel's ray, id 0) elsewhere."""
    e = make(obs_mode=obs_mode, hybrid_obs=True, render_mode=None, replace_objs=False)
    try:
        obs, _ = e.reset(seed=0)
        u = e.unwrapped
        raw, fg, bg, cam = base_camera_truth(u)
        bg_depth = bg.surface_depth(0.5)
        surface = ~fg & torch.isfinite(bg_depth)
        assert surface.float().mean() > 0.3 and fg.float().mean() > 0.05
        raw_seg = raw["segmentation"][0, ..., 0]
        if obs_mode == "pointcloud":
            pc = obs["pointcloud"]
            xyzw = pc["xyzw"][0].reshape(128, 128, 4)
            seg = pc["segmentation"][0].reshape(128, 128)
            rgb = pc["rgb"][0].reshape(128, 128, 3)
            # splat points: on the pixel's ray at the splat's depth, in the world, valid
            v, uu = torch.nonzero(surface, as_tuple=True)
            d = bg_depth[v, uu].double()
            p_cam = torch.stack(
                [(uu + 0.5 - cam.cx) / cam.fx * d, (v + 0.5 - cam.cy) / cam.fy * d, d, d * 0 + 1],
                -1,
            )
            world = (p_cam @ torch.tensor(np.linalg.inv(cam.world_to_cam)).T)[:, :3]
            assert (xyzw[surface][:, :3].double() - world).abs().max() < 3e-3
            assert (xyzw[surface][:, 3] == 1).all() and (seg[surface] == 0).all()
            # simulator points: ManiSkill's own conversion of the raw textures
            pos = raw["position"][0].double() / 1000.0
            homo = torch.cat([pos, (raw_seg != 0)[..., None].double()], -1)
            sim = homo @ obs["sensor_param"]["base_camera"]["cam2world_gl"][0].double().T
            assert torch.allclose(xyzw[fg].double(), sim[fg], atol=1e-5)
            assert torch.equal(seg[fg], raw_seg[fg])
            # no surface at all: ManiSkill's empty point (w = 0)
            assert (xyzw[~fg & ~surface][:, 3] == 0).all()
            assert torch.equal(rgb[surface], bg.rgb_uint8()[surface])
            return
        data = obs["sensor_data"]["base_camera"]
        depth = data["depth"][0, ..., 0]
        assert torch.equal(depth[fg], raw["depth"][0, ..., 0][fg])
        splat_mm = (bg_depth * 1000).round()
        assert (depth[surface].double() - splat_mm[surface].double()).abs().max() <= 2
        assert (depth[~fg & ~surface] == 0).all()
        assert torch.equal(data["rgb"][0][surface], bg.rgb_uint8()[surface])
        if "segmentation" in data:
            seg = data["segmentation"][0, ..., 0]
            assert torch.equal(seg[fg], raw_seg[fg]) and (seg[~fg] == 0).all()
        # the composited depth is what the depth test decided: nothing nearer than the splat
        # surface was dropped, and no simulator pixel shows behind it
        assert ((depth[fg].double() / 1000) <= bg_depth[fg].double() + 1e-3).all()
    finally:
        e.close()


def test_maniskill_cpu_wrapper_and_record_episode_write_hybrid_videos(tmp_path):
    """ManiSkill's own CPUGymWrapper and RecordEpisode, unchanged, on render_mode="hybrid":
    the video's frames are the composited ones, not the plain simulator's."""
    import imageio.v3 as iio
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper
    from mani_skill.utils.wrappers.record import RecordEpisode

    env = RecordEpisode(
        CPUGymWrapper(make(obs_mode="state", replace_objs=False)),
        output_dir=str(tmp_path),
        save_trajectory=False,
        max_steps_per_video=4,
        video_fps=20,
    )
    try:
        assert env.render_mode == "rgb_array" and env.unwrapped.render_hybrid
        env.reset(seed=0)
        hybrid = env.render()
        plain = env.unwrapped.render_simulated()[0].numpy()
        assert hybrid.shape == (256, 256, 3) and hybrid.dtype == np.uint8
        for _ in range(4):
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    finally:
        env.close()
    videos = sorted(tmp_path.glob("*.mp4"))
    assert videos, "RecordEpisode wrote no video"
    first = iio.imread(videos[0], index=0).astype(float)
    assert np.abs(first - hybrid).mean() < 6, "the video shows the hybrid frames"
    assert np.abs(first - plain).mean() > 5 * np.abs(first - hybrid).mean()


def test_the_render_camera_is_framed_on_each_configurations_robot_and_table():
    """Without an eye or target, the render camera stands past the table's centre, away from
    the robot, at every configuration; given ones are kept."""
    e = make(obs_mode="state", render_mode="rgb_array")
    try:
        u = e.unwrapped
        for seed in (0, 7, 11):
            e.reset(seed=seed, options=dict(reconfigure=True))
            cam = u.scene.human_render_cameras["render_camera"]
            eye = cam.camera.get_model_matrix()[0, :3, 3].numpy()
            robot = u.layouts[0].pose(u.layouts[0].robot).p
            top = u.layout_scene.episodes.top
            centre = ((top.lo[0] + top.hi[0]) / 2).numpy()
            away = (centre - np.asarray(robot[:2])) / np.linalg.norm(centre - robot[:2])
            np.testing.assert_allclose(eye[:2], centre + u.render_camera_back * away, atol=1e-4)
            assert eye[2] == pytest.approx(float(u.layout_scene.top_z[0]) + 0.34, abs=1e-4)
    finally:
        e.close()
    fixed = make(obs_mode="state", render_mode="rgb_array", camera_cfg=dict(camera_eye=[1, 1, 2]))
    try:
        fixed.reset(seed=0)
        cam = fixed.unwrapped.scene.human_render_cameras["render_camera"]
        np.testing.assert_allclose(cam.camera.get_model_matrix()[0, :3, 3].numpy(), [1, 1, 2])
    finally:
        fixed.close()
