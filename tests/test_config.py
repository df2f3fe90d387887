"""Config files: merged in order, every key checked, reachable through gym.make and the CLI."""

import json
import subprocess
import sys

import gymnasium as gym
import pytest
from conftest import DEFAULT_LAYOUT, ROOT

import embodied_envs  # noqa: F401
from embodied_envs.cli.main import main
from embodied_envs.config import ConfigError, load_config, merge_config
from embodied_envs.envs import PickEmbodiedGenEnv
from embodied_envs.layout import GoalRegion, PlacementLimits

KNOWN = ["robot_init_qpos_noise", "placement_limits", "goal_region", "camera_cfg", "obs_mode"]


def write(path, text):
    path.write_text(text)
    return path


def test_later_files_override_earlier_ones_key_by_key(tmp_path):
    a = write(
        tmp_path / "a.yaml",
        "robot_init_qpos_noise: 0.1\nobs_mode: state\n"
        "placement_limits: {reach_max: 0.7, clearance: 0.02}\n",
    )
    b = write(
        tmp_path / "b.json",
        json.dumps({"robot_init_qpos_noise": 0.0, "placement_limits": {"clearance": 0.03}}),
    )
    merged = load_config([a, b], known=KNOWN)
    assert merged == {
        "robot_init_qpos_noise": 0.0,  # b wins
        "obs_mode": "state",  # only in a
        "placement_limits": {"reach_max": 0.7, "clearance": 0.03},  # merged field by field
    }
    assert load_config([b, a], known=KNOWN)["robot_init_qpos_noise"] == 0.1
    # keywords over files: dict settings merge, the rest replace
    over = merge_config(merged, {"placement_limits": {"reach_max": 0.6}, "obs_mode": "rgb"})
    assert over["placement_limits"] == {"reach_max": 0.6, "clearance": 0.03}
    assert over["obs_mode"] == "rgb"
    assert merged["placement_limits"]["reach_max"] == 0.7  # inputs are not modified


@pytest.mark.parametrize(
    "text, words",
    [
        ("robot_init_qpos_nosie: 0.1\n", ["unknown key(s) ['robot_init_qpos_nosie']", "known:"]),
        ("placement_limits: {reach: 0.7}\n", ["placement_limits: unknown key(s) ['reach']",
                                               "reach_max"]),
        ("goal_region: {reach: [0.3, 0.6]}\n", ["goal_region: unknown key(s) ['reach']", "inset"]),
        ("camera_cfg: {eye: [1, 0, 1]}\n", ["camera_cfg: unknown key(s) ['eye']", "camera_eye"]),
        ("placement_limits: 0.7\n", ["placement_limits must be a mapping"]),
        ("- robot_init_qpos_noise\n", ["holds a mapping of env keywords", "got a list"]),
        ("robot_init_qpos_noise: [0.1\n", ["not valid YAML"]),
    ],
)  # fmt: skip
def test_bad_files_name_the_file_and_the_key(tmp_path, text, words):
    path = write(tmp_path / "bad.yaml", text)
    with pytest.raises(ConfigError) as e:
        load_config([path], known=KNOWN)
    message = str(e.value)
    assert message.startswith(str(path))
    for w in words:
        assert w in message


def env_config_of(path):
    return load_config([path], PickEmbodiedGenEnv.keywords(), PickEmbodiedGenEnv.check_keyword)


@pytest.mark.parametrize(
    "text, words",
    [
        ('replace_objs: "false"\n', ["replace_objs='false'", "True or False", "not a string"]),
        ("hybrid_obs: yes please\n", ["hybrid_obs='yes please'"]),
        ('robot_init_qpos_noise: "0.1"\n', ["robot_init_qpos_noise='0.1' must be float"]),
        ("robot_init_qpos_noise: 1000\n", ["robot_init_qpos_noise=1000", "[0.0, 0.5]"]),
        ("reconfiguration_freq: 1.5\n", ["reconfiguration_freq=1.5 must be int or None"]),
        ("obs_mode: 3\n", ["obs_mode=3 must be"]),
        ("placement_limits: {batch: 0}\n", ["placement_limits.batch=0", "[1, 100000]"]),
        ("goal_region: {height: [50, 60]}\n", ["goal_region.height[0]=50"]),
        ("camera_cfg: {image_hw: [16384, 16384]}\n", ["[16384, 16384]", "at most 8192 px"]),
        ("init_3dgs_quat: [0, 0, 0, 0]\n", ["init_3dgs_quat", "unit quaternion"]),
        ("enable_grasp: &a [1, 2]\nhybrid_obs: *a\n", ["line 2", "alias *a is refused"]),
        ("obs_mode: state\nobs_mode: rgb\n", ["line 2", "'obs_mode' appears twice"]),
    ],
)  # fmt: skip
def test_values_are_checked_by_type_and_range_naming_the_file(tmp_path, text, words):
    path = write(tmp_path / "bad.yaml", text)
    with pytest.raises(ConfigError) as e:
        env_config_of(path)
    assert str(e.value).startswith(str(path)), str(e.value)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_only_small_regular_files_are_read(tmp_path):
    import os
    import time

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # reading would block until a writer comes
    big = write(tmp_path / "big.yaml", "# " + "x" * (2 << 20) + "\n")
    dup = write(tmp_path / "dup.json", '{"obs_mode": "state", "obs_mode": "rgb"}')
    for path, words in (
        ("/dev/zero", "not a regular file"),
        (fifo, "not a regular file"),
        (big, "over the 1,048,576 bytes"),
        (dup, "'obs_mode' appears twice"),
    ):
        t = time.perf_counter()
        with pytest.raises(ConfigError) as e:
            env_config_of(path)
        assert str(e.value).startswith(str(path)) and words in str(e.value), str(e.value)
        assert time.perf_counter() - t < 2


def test_a_bad_config_value_is_one_line_from_the_cli(tmp_path, capsys):
    path = write(tmp_path / "c.yaml", 'replace_objs: "false"\n')
    code = main(["eval", "--policy", "zero", "--config", str(path), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and str(path) in err and "replace_objs" in err
    assert not (tmp_path / "o").exists()


def test_the_known_keys_are_the_envs_keywords(tmp_path):
    path = write(tmp_path / "c.yaml", "num_env: 2\n")
    with pytest.raises(ConfigError) as e:
        load_config([path], PickEmbodiedGenEnv.keywords())
    for name in ("layout_file", "placement_limits", "goal_region", "num_envs", "obs_mode"):
        assert f"'{name}'" in str(e.value)


def test_gym_make_config_keyword(tmp_path):
    a = write(
        tmp_path / "a.yaml",
        "robot_init_qpos_noise: 0.05\ngoal_region: {inset: 0.15, height: [0.1, 0.2]}\n"
        "placement_limits: {reach_max: 0.74}\ncamera_cfg: {image_hw: [64, 96]}\n",
    )
    b = write(tmp_path / "b.yaml", "goal_region: {inset: 0.12}\n")
    env = gym.make(
        "PickEmbodiedGen-v1",
        config=[str(a), str(b)],
        layout_file=str(DEFAULT_LAYOUT),
        robot_init_qpos_noise=0.0,  # a keyword wins over the files
        render_mode="rgb_array",
    )
    try:
        u = env.unwrapped
        assert u.robot_init_qpos_noise == 0.0
        assert u.goal_region == GoalRegion(inset=0.12, height=(0.1, 0.2))
        assert u.placement_limits == PlacementLimits(reach_max=0.74)
        env.reset(seed=0)
        assert env.render().shape[-3:] == (64, 96, 3)
        # the spec (RecordEpisode's env_kwargs) spells the merged values out
        kwargs = u.spec.kwargs
        assert "config" not in kwargs
        assert kwargs["goal_region"] == {"inset": 0.12, "height": [0.1, 0.2]}
        assert kwargs["robot_init_qpos_noise"] == 0.0
        remade = gym.make("PickEmbodiedGen-v1", **kwargs)
        assert remade.unwrapped.goal_region == u.goal_region
        remade.close()
    finally:
        env.close()


def test_goals_follow_the_configured_reach_and_inset(tmp_path):
    cfg = write(
        tmp_path / "g.yaml", "goal_region: {inset: 0.15}\nplacement_limits: {reach_max: 0.8}\n"
    )
    env = gym.make("PickEmbodiedGen-v1", config=str(cfg), layout_file=str(DEFAULT_LAYOUT))
    try:
        u = env.unwrapped
        robot = u.layout_scene.robot_poses[0, :2]
        dists = []
        for seed in range(40):
            env.reset(seed=seed)
            dists.append(float((u.goal_site.pose.p[0, :2] - robot).norm()))
        near, far = GoalRegion(inset=0.15).distance_band(PlacementLimits(reach_max=0.8))
        assert (near, far) == (PlacementLimits().reach_min + 0.15, 0.8 - 0.15)
        assert min(dists) >= near - 1e-5 and max(dists) <= far + 1e-5
        assert max(dists) - min(dists) > 0.1  # spread over the band, not one point
    finally:
        env.close()


def test_cli_config_files(tmp_path, capsys):
    owned = write(tmp_path / "owned.yaml", "control_mode: pd_ee_delta_pose\n")
    assert main(["collect", "--config", str(owned), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "control_mode is set by this command" in err and str(owned) in err
    typo = write(tmp_path / "typo.yaml", "robot_init_qpos_nosie: 0\n")
    assert main(["demo", "--config", str(typo), "--out", str(tmp_path / "d")]) == 1
    err = capsys.readouterr().err
    assert "unknown key(s) ['robot_init_qpos_nosie']" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "d").exists()


def test_import_and_layout_commands_do_not_load_the_simulator():
    """``import embodied_envs`` registers the env for gym.make without importing ManiSkill,
    SAPIEN or torch, and ``layout validate`` (YAML, meshes, the splat PLY) runs without them."""
    code = (
        "import sys, gymnasium as gym, embodied_envs\n"
        "assert 'PickEmbodiedGen-v1' in gym.registry\n"
        "from embodied_envs.cli.main import main\n"
        f"assert main(['layout', 'validate', {str(DEFAULT_LAYOUT)!r}]) == 0\n"
        "top = {m.split('.')[0] for m in sys.modules}\n"
        "heavy = sorted(top & {'torch', 'mani_skill', 'sapien'})\n"
        "print('heavy', heavy)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert "heavy []" in out.stdout


def test_relative_paths_in_a_config_file_are_relative_to_its_folder(tmp_path, monkeypatch):
    folder = tmp_path / "configs"
    folder.mkdir()
    cfg = write(
        folder / "c.yaml",
        "layout_file: [scenes/a.json, 'scenes/*.json', /abs/b.json, ~/c.json]\n",
    )
    monkeypatch.chdir(tmp_path)  # the working folder is not the config's
    got = load_config("configs/c.yaml", ["layout_file"])["layout_file"]
    assert got == [str(folder / "scenes/a.json"), str(folder / "scenes/*.json"), "/abs/b.json",
                   "~/c.json"]  # fmt: skip
    write(cfg, "layout_file: one.json\n")
    assert load_config(cfg, ["layout_file"]) == {"layout_file": str(folder / "one.json")}
    odd = tmp_path / "[odd]"  # a glob matches the config's folder by its own name
    odd.mkdir()
    write(odd / "c.yaml", "layout_file: 'x*.json'\n")
    assert (
        load_config(odd / "c.yaml", ["layout_file"])["layout_file"] == f"{tmp_path}/[[]odd]/x*.json"
    )


def test_a_config_files_layout_works_from_any_folder_and_a_keyword_from_the_working_one(
    scene_copy, monkeypatch
):
    """A config file naming ../../layouts/round_table.json: found from another working
    folder. A layout_file keyword is relative to the working folder, and wins over the file."""
    (scene_copy / "configs" / "nested").mkdir(parents=True)
    cfg = write(
        scene_copy / "configs" / "nested" / "a.yaml",
        "layout_file: ../../layouts/round_table.json\n",
    )
    work = scene_copy / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    env = gym.make("PickEmbodiedGen-v1", config=str(cfg))
    try:
        assert env.unwrapped.layout_file == (scene_copy / "layouts" / "round_table.json").resolve()
    finally:
        env.close()
    monkeypatch.chdir(scene_copy)
    env = gym.make("PickEmbodiedGen-v1", config=str(cfg), layout_file="layouts/default.json")
    try:
        assert env.unwrapped.layout_file == (scene_copy / "layouts" / "default.json").resolve()
    finally:
        env.close()
