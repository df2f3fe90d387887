"""The visual recipe: ``collect --obs-mode rgb --hybrid-obs --rooms`` records what a
visuomotor learner needs, ``train_policy.py`` trains a policy from its frames in seconds, and
``eval --hybrid-obs`` runs it on the frames the dataset holds."""

import json
import sys
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch
from conftest import DEFAULT_LAYOUT

from embodied_envs.cli.main import main
from embodied_envs.pipelines.policies import load_policy

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "recipes"))
import train_policy  # noqa: E402
import visual  # noqa: E402

MODE = "pd_joint_delta_pos"
SIDE = 40  # px: the camera of these tests (the recipe's default is 64)
SEED = 5


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two hybrid rgb demos over the shipped rooms, and a policy trained on them for seconds."""
    root = tmp_path_factory.mktemp("visual")
    code = main([
        "collect", "--layout", str(DEFAULT_LAYOUT), "--num", "2", "--seed", str(SEED),
        "--obs-mode", "rgb", "--hybrid-obs", "--rooms", "shipped", "--camera-size", str(SIDE),
        "--control-mode", MODE, "--out", str(root / "demos"),
    ])  # fmt: skip
    assert code == 0
    demos = root / "demos" / DEFAULT_LAYOUT.stem / "trajectory.h5"
    train_policy.main([
        "--demos", str(demos), "--out", str(root / "run"), "--minutes", "0.05", "--chunk", "4",
        "--hidden", "32", "--batch-size", "16",
    ])  # fmt: skip
    return demos, root / "run"


def test_the_dataset_holds_frames_joints_and_goal_and_no_object_poses(dataset):
    demos, _ = dataset
    meta = json.loads(demos.with_suffix(".json").read_text())
    kwargs = meta["env_info"]["env_kwargs"]
    assert kwargs["hybrid_obs"] is True and kwargs["rooms"] == ["shipped"]
    assert kwargs["sensor_configs"] == dict(width=SIDE, height=SIDE)
    with h5py.File(demos) as f:
        obs = f["traj_0/obs"]
        rgb = obs["sensor_data/base_camera/rgb"]
        assert rgb.dtype == np.uint8 and rgb.shape[1:] == (SIDE, SIDE, 3)
        assert rgb.compression == "gzip"
        assert set(obs["extra"]) == {"is_grasped", "tcp_pose", "goal_pos", "task_kind"}
        assert set(obs["agent"]) == {"qpos", "qvel"}
        assert "depth" not in obs["sensor_data/base_camera"]


def test_eval_hybrid_obs_gives_the_frames_the_dataset_holds(dataset):
    """The env eval makes for the dataset's flags, reset with a demo's seed, observes the
    dataset's first frame (the same room, the same composite)."""
    demos, _ = dataset
    meta = json.loads(demos.with_suffix(".json").read_text())
    kwargs = meta["env_info"]["env_kwargs"]
    env = gym.make("PickEmbodiedGen-v1", **kwargs)
    try:
        for ep in meta["episodes"]:
            obs, _ = env.reset(seed=ep["episode_seed"])
            with h5py.File(demos) as f:
                first = f[f"traj_{ep['episode_id']}/obs/sensor_data/base_camera/rgb"][0]
            got = obs["sensor_data"]["base_camera"]["rgb"][0].numpy()
            assert np.abs(got.astype(int) - first.astype(int)).max() <= 1
    finally:
        env.close()


def test_the_visual_policy_trains_exports_and_eval_runs_it(dataset, tmp_path, capsys):
    demos, out = dataset
    info = json.loads((out / "train.json").read_text())
    assert info["kind"] == "visual" and info["image_hw"] == [SIDE, SIDE]
    assert info["iterations"] > 0 and info["state_keys"] == list(visual.STATE_KEYS)
    assert info["aux_target"] == "can" and info["final_aux_loss"] > 0
    module = torch.jit.load(str(out / "policy.pt"))
    assert module.camera == "base_camera" and list(module.image_hw) == [SIDE, SIDE]
    code = main([
        "eval", "--policy", str(out / "policy.pt"), "--obs-mode", "rgb", "--hybrid-obs",
        "--rooms", "shipped", "--camera-size", str(SIDE), "--control-mode", MODE,
        "--episodes", "1", "--seed", "100", "--max-episode-steps", "8",
        "--out", str(tmp_path / "ev"),
    ])  # fmt: skip
    assert code == 0, capsys.readouterr().out
    episodes = json.loads((tmp_path / "ev" / "episodes.json").read_text())
    assert episodes[0]["steps"] == 8


def test_the_policy_sees_the_frame_and_the_goal(dataset):
    """Its action depends on the image and on the goal (not on one input alone)."""
    _, out = dataset
    policy = load_policy(str(out / "policy.pt"), env=None)
    module = torch.jit.load(str(out / "policy.pt"))
    gen = torch.Generator().manual_seed(0)
    image = torch.randint(0, 255, (1, SIDE, SIDE, 3), dtype=torch.uint8, generator=gen)
    obs = {
        "agent": {"qpos": torch.zeros(1, 9), "qvel": torch.zeros(1, 9)},
        "extra": {"tcp_pose": torch.zeros(1, 7), "goal_pos": torch.zeros(1, 3)},
        "sensor_data": {"base_camera": {"rgb": image}},
    }

    def act(o):
        module.reset()
        return policy.act(o)

    base = act(obs)
    other_image = dict(obs, sensor_data={"base_camera": {"rgb": 255 - image}})
    other_goal = dict(obs, extra={"tcp_pose": torch.zeros(1, 7), "goal_pos": torch.ones(1, 3)})
    assert not torch.allclose(base, act(other_image))
    assert not torch.allclose(base, act(other_goal))


def test_the_augmentation_shifts_and_jitters_within_its_bounds():
    gen = torch.Generator().manual_seed(0)
    images = torch.rand(64, 3, 16, 16, generator=gen)
    out = visual.augment(images, gen)
    assert out.shape == images.shape and out.min() >= 0 and out.max() <= 1
    assert not torch.allclose(out, images)
    # a constant image stays constant under shifts: only the colour jitter changes it
    flat = torch.full((64, 3, 16, 16), 0.5)
    jittered = visual.augment(flat, gen)
    assert torch.allclose(jittered, jittered[:, :, :1, :1].expand_as(jittered))
    gains = jittered[:, :, 0, 0] / 0.5
    low = (1 - visual.BRIGHTNESS) * (1 - visual.GAIN)
    high = (1 + visual.BRIGHTNESS) * (1 + visual.GAIN)
    assert gains.min() >= low - 1e-6 and gains.max() <= high + 1e-6
    assert gains.std() > 0.02  # jittered per image


def test_a_dataset_without_a_field_the_policy_needs_is_refused_naming_it(dataset, tmp_path):
    demos, _ = dataset
    broken = tmp_path / "trajectory.h5"
    with h5py.File(demos) as src, h5py.File(broken, "w") as dst:
        for name in src:
            src.copy(name, dst)
        del dst["traj_0/obs/extra/goal_pos"]
    broken.with_suffix(".json").write_text(demos.with_suffix(".json").read_text())
    assert visual.is_visual(demos) and visual.is_visual(broken)
    with pytest.raises(SystemExit, match="has no obs/extra/goal_pos. Fix: collect with --obs-mode"):
        train_policy.main(
            ["--demos", str(broken), "--out", str(tmp_path / "r"), "--minutes", "0.01"]
        )
    assert not (tmp_path / "r" / "policy.pt").exists()


def test_a_visual_policy_on_state_observations_is_one_line(dataset, tmp_path, capsys):
    _, out = dataset
    code = main([
        "eval", "--policy", str(out / "policy.pt"), "--obs-mode", "state", "--control-mode", MODE,
        "--episodes", "1", "--max-episode-steps", "2", "--out", str(tmp_path / "ev"),
    ])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 1 and "is a visual policy" in text and "--obs-mode rgb" in text
    code = main([
        "eval", "--policy", str(out / "policy.pt"), "--obs-mode", "rgb", "--camera-size", "32",
        "--control-mode", MODE, "--episodes", "1", "--max-episode-steps", "2",
        "--out", str(tmp_path / "ev2"),
    ])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 1 and f"trained on {SIDE}x{SIDE} frames" in text
    assert f"--camera-size {SIDE}" in text


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--obs-mode", "rgb", "--rooms", "shipped"], "--rooms are splat backgrounds"),
        (["--obs-mode", "state", "--hybrid-obs"], "--obs-mode state has none"),
        (["--obs-mode", "rgb", "--hybrid-obs", "--rooms", "/nowhere"], "holds no room"),
        (["--obs-mode", "rgb", "--robot-visual-faces", "10"], "--robot-visual-faces: "),
    ],
)
def test_bad_camera_flags_are_one_line(flags, words, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["collect", "--layout", str(DEFAULT_LAYOUT), "--num", "1", *flags,
              "--out", str(tmp_path / "d")])  # fmt: skip
    assert words in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "d").exists()


def test_a_room_whose_splat_is_broken_is_refused_naming_the_file(tmp_path):
    room = tmp_path / "room"
    room.mkdir()
    (room / "gs_model.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nend_header\n")
    with pytest.raises(SystemExit) as e:
        main(["collect", "--layout", str(DEFAULT_LAYOUT), "--num", "1", "--obs-mode", "rgb",
              "--hybrid-obs", "--rooms", str(room), "--out", str(tmp_path / "d")])  # fmt: skip
    assert str(room / "gs_model.ply") in str(e.value) and "\n" not in str(e.value)


def test_the_auxiliary_target_is_the_movers_recorded_position_from_the_tcp(dataset):
    """Training only: the can's recorded position less the TCP's, and the can's position."""
    demos, _ = dataset
    meta = json.loads(demos.with_suffix(".json").read_text())
    _, _, _, aux = visual.load_visual_episodes(demos, meta["episodes"][:1], "can")
    with h5py.File(demos) as f:
        traj = f[f"traj_{meta['episodes'][0]['episode_id']}"]
        can = traj["env_states/actors/can"][:, :3]
        tcp = traj["obs/extra/tcp_pose"][:, :3]
    np.testing.assert_allclose(aux[0][:, 3:], can, atol=1e-6)
    np.testing.assert_allclose(aux[0][:, :3], can - tcp, atol=1e-6)
    _, _, _, none = visual.load_visual_episodes(demos, meta["episodes"][:1], "no_such_actor")
    assert np.isnan(none[0]).all()
