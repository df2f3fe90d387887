"""`embodied-envs collect` and `replay`: datasets that ManiSkill's own tools read and replay."""

import json
import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest
from conftest import DATA, DEFAULT_LAYOUT

CLI = [sys.executable, "-m", "embodied_envs.cli.main"]
ENV = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}


def run(args, cwd, check=True):
    return subprocess.run(
        CLI + args, cwd=cwd, env=ENV, capture_output=True, text=True, timeout=600, check=check
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three seeded demonstrations of the default layout, collected from another folder with
    a relative layout path and a config file, then moved (the config file is deleted)."""
    work = tmp_path_factory.mktemp("collect")
    layout = os.path.relpath(DEFAULT_LAYOUT, work)
    (work / "cfg.yaml").write_text("goal_region: {inset: 0.12}\n")
    args = ["--num", "3", "--seed", "5", "--out", "out", "--config", "cfg.yaml"]
    res = run(["collect", "--layout", layout, *args], work, check=False)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "default.json: 3 demonstrations" in res.stdout, res.stdout + res.stderr
    (work / "cfg.yaml").unlink()  # replays must not need it
    moved = work / "moved"
    shutil.move(work / "out" / "default", moved)
    assert not any(p.name.startswith(".") for p in (work / "out").iterdir()), "no leftovers"
    return moved


def test_dataset_is_maniskill_trajectory_format(dataset):
    meta = json.loads((dataset / "trajectory.json").read_text())
    info = meta["env_info"]
    assert info["env_id"] == "embodied_envs:PickEmbodiedGen-v1"  # gymnasium imports us
    assert info["env_kwargs"]["layout_file"] == str(DEFAULT_LAYOUT)  # absolute: any cwd
    assert info["env_kwargs"]["control_mode"] == "pd_joint_pos"
    assert info["env_kwargs"]["goal_region"] == {"inset": 0.12}  # the config file's, spelled out
    assert "config" not in info["env_kwargs"]
    assert info["max_episode_steps"] == 500
    assert meta["source_type"] == "motionplanning" and "PickPlaceSolver" in meta["source_desc"]
    episodes = meta["episodes"]
    assert [e["episode_seed"] for e in episodes] == [5, 6, 7]
    task = json.loads(DEFAULT_LAYOUT.read_text())["relation"]["task_desc"]
    assert {(e["instruction"], e["layout_file"]) for e in episodes} == {(task, str(DEFAULT_LAYOUT))}
    assert [e["episode_id"] for e in episodes] == [0, 1, 2]
    summary = json.loads((dataset / "summary.json").read_text())
    assert summary["attempted"] == 3 and summary["kept"] == 3
    assert summary["successes"] == sum(e["success"] for e in episodes)
    with h5py.File(dataset / "trajectory.h5") as f:
        for e in episodes:
            g = f[f"traj_{e['episode_id']}"]
            n = e["elapsed_steps"]
            assert g["actions"].shape == (n, 8) and np.isfinite(g["actions"][:]).all()
            assert not g["truncated"][:-1].any(), "no step before the last is truncated"
            assert bool(g["success"][-1]) == e["success"]
            assert n <= 500
            assert g["env_states/actors/goal_site"].shape[0] == n + 1


def test_maniskill_loader_and_replay_from_another_folder(dataset, tmp_path):
    """ManiSkill's replay_trajectory converts to rgb observations from any working folder;
    the replayed states are the recorded ones; ManiSkillTrajectoryDataset reads the result."""
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset

    traj = dataset / "trajectory.h5"
    res = run(
        ["replay", "--traj-path", str(traj), "-o", "rgb", "--save-traj", "--allow-failure"],
        tmp_path,
    )
    out = dataset / "trajectory.rgb.pd_joint_pos.physx_cpu.h5"
    assert out.is_file(), res.stdout + res.stderr
    with h5py.File(traj) as a, h5py.File(out) as b:
        for key in a:
            rec, rep = a[key]["env_states/actors"], b[key]["env_states/actors"]
            for actor in rec:
                np.testing.assert_allclose(rep[actor][:], rec[actor][:], atol=1e-4)
            rgb = b[key]["obs/sensor_data/base_camera/rgb"]
            assert rgb.shape == (len(a[key]["actions"]) + 1, 128, 128, 3)
    data = ManiSkillTrajectoryDataset(str(out), load_count=-1, success_only=False)
    episodes = json.loads((dataset / "trajectory.json").read_text())["episodes"]
    assert len(data) == sum(e["elapsed_steps"] for e in episodes)
    item = data[0]
    assert item["obs"]["sensor_data"]["base_camera"]["rgb"].shape == (128, 128, 3)
    assert item["action"].shape == (8,)


def test_impossible_only_success_target_ends_with_a_clear_error(tmp_path):
    res = run(
        ["collect", "--num", "3", "--only-success", "--max-attempts", "1", "--out", "out"],
        tmp_path,
        check=False,
    )
    assert res.returncode == 1
    assert "of 3 successful demonstrations after 1 attempts (success rate" in res.stdout
    assert "Fix: raise --max-attempts" in res.stdout
    assert list((tmp_path / "out").iterdir()) == [], "nothing is left behind"


def test_bad_arguments_fail_in_one_line_before_simulation(tmp_path):
    for args, words in (
        (["collect", "--num", "0"], "0 is not a positive integer"),
        (["collect", "--seed", "-5"], "seed -5 is outside [0, 4294967295]"),
        (["collect", "--seed", str(2**32)], "seed 4294967296 is outside [0, 4294967295]"),
        (["collect", "--seed", str(2**32 - 2), "--num", "3"], "reaches seed 4294967296"),
        (
            ["eval", "--policy", "zero", "--seed", str(2**32 - 1), "--episodes", "2"],
            "Fix: --seed 4294967294 or lower",
        ),
        (["demo", "--seed", str(2**32 - 1), "--num-envs", "2"], "reaches seed 4294967296"),
        (["collect", "--layout", "missing.json"], "missing.json"),
    ):
        res = run(args + ["--out", "out"], tmp_path, check=False)
        assert res.returncode != 0 and words in res.stderr + res.stdout, args
        assert "Traceback" not in res.stderr, args
        assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("mode", ["pd_ee_delta_pose", "pd_ee_pose"])
def test_end_effector_conversion_on_a_yawed_robot_base(dataset, tmp_path, mode):
    """The shipped layouts yaw the robot base to face the table; `replay -c` converts every
    successful demo (ManiSkill 3.0.1's own converter saved 4/10 and 0/10 of such demos)."""
    meta = json.loads((dataset / "trajectory.json").read_text())
    robot = json.loads(DEFAULT_LAYOUT.read_text())["position"]["franka"]
    assert abs(robot[5]) > 0.1, "the robot base is yawed in this layout"
    work = tmp_path / "data"
    shutil.copytree(dataset, work)
    res = run(
        ["replay", "--traj-path", str(work / "trajectory.h5"), "-c", mode, "--save-traj"], tmp_path
    )
    successes = sum(e["success"] for e in meta["episodes"])
    assert f"{successes}/{len(meta['episodes'])}=" in res.stdout, res.stdout[-2000:]
    out = json.loads(next(work.glob(f"trajectory.none.{mode}.*.json")).read_text())
    assert {e["control_mode"] for e in out["episodes"]} == {mode}


def test_lerobot_conversion_with_maniskill_converter(dataset, tmp_path):
    """rgb observations by replay, then `embodied-envs lerobot`: ManiSkill's convert_to_lerobot
    (the lerobot extra) told the instruction, the control rate and the robot."""
    import pandas as pd

    work = tmp_path / "data"
    shutil.copytree(dataset, work, ignore=shutil.ignore_patterns("trajectory.*.*"))
    run(
        ["replay", "--traj-path", str(work / "trajectory.h5"), "-o", "rgb", "--save-traj",
         "--count", "1", "--allow-failure"],
        tmp_path,
    )  # fmt: skip
    rgb = next(work.glob("trajectory.rgb.*.h5"))
    run(["lerobot", "--traj-path", str(rgb), "--output-dir", str(tmp_path / "lerobot"),
         "--image-size", "128"], tmp_path)  # fmt: skip
    info = json.loads((tmp_path / "lerobot" / "meta" / "info.json").read_text())
    task = json.loads(DEFAULT_LAYOUT.read_text())["relation"]["task_desc"]
    assert info["fps"] == 50 and info["robot_type"] == "panda", "the env's rate and robot"
    tasks = pd.read_parquet(tmp_path / "lerobot" / "meta" / "tasks.parquet")
    assert list(tasks.index) == [task], "the layout's instruction, not the env id"
    steps = json.loads((dataset / "trajectory.json").read_text())["episodes"][0]["elapsed_steps"]
    assert info["total_episodes"] == 1 and info["total_frames"] == steps
    frames = pd.read_parquet(next((tmp_path / "lerobot" / "data").rglob("*.parquet")))
    assert len(frames) == steps and len(frames["action"].iloc[0]) == 8
    assert len(frames["observation.state"].iloc[0]) == 9  # Panda qpos
    assert next((tmp_path / "lerobot" / "videos").rglob("*.mp4")).stat().st_size > 1000


def test_shards_on_disjoint_seeds_merge_with_maniskill(dataset, tmp_path):
    """Two machines collect disjoint seed ranges; ManiSkill's merge_trajectory joins them."""
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset

    shutil.copytree(
        dataset, tmp_path / "shard0" / "default", ignore=shutil.ignore_patterns("*.*.*")
    )
    run(["collect", "--num", "1", "--seed", "100", "--out", "shard1"], tmp_path)
    subprocess.run(
        [sys.executable, "-m", "mani_skill.trajectory.merge_trajectory", "-i", "shard0", "shard1",
         "-o", "all/trajectory.h5"],
        cwd=tmp_path, env=ENV, check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    merged = json.loads((tmp_path / "all" / "trajectory.json").read_text())
    assert [e["episode_seed"] for e in merged["episodes"]] == [5, 6, 7, 100]
    assert merged["env_info"]["env_kwargs"]["layout_file"] == str(DEFAULT_LAYOUT)
    data = ManiSkillTrajectoryDataset(
        str(tmp_path / "all" / "trajectory.h5"), load_count=-1, success_only=False
    )
    assert len(data) == sum(e["elapsed_steps"] for e in merged["episodes"])


def test_replay_refuses_broken_datasets_in_one_line(dataset, tmp_path, scene_copy):
    """Corrupt files, an unknown env id, a deleted layout: one line naming the file, exit 1,
    before ManiSkill opens anything; a changed scene is said before replaying."""
    meta = json.loads((dataset / "trajectory.json").read_text())
    assert len(meta["embodied_envs"]["layout_sha256"]) == 64, "collect records the scene"

    def copy(name, edit_meta=None, h5=None):
        folder = tmp_path / name
        shutil.copytree(dataset, folder, ignore=shutil.ignore_patterns("*.*.*"))
        if edit_meta is not None:
            m = json.loads((folder / "trajectory.json").read_text())
            edit_meta(m)
            (folder / "trajectory.json").write_text(json.dumps(m))
        if h5 is not None:
            (folder / "trajectory.h5").write_bytes(h5)
        return folder / "trajectory.h5"

    def set_env_id(m):
        m["env_info"]["env_id"] = "NoSuchEnv-v9"

    def set_layout(m):
        m["env_info"]["env_kwargs"]["layout_file"] = str(tmp_path / "gone" / "layout.json")

    cases = [
        (copy("corrupt", h5=b"not hdf5 at all"), "not a readable HDF5 trajectory file"),
        (copy("env_id", set_env_id), "'NoSuchEnv-v9' is not a registered env"),
        (copy("layout", set_layout), "does not exist any more"),
        (tmp_path / "missing" / "trajectory.h5", "no such trajectory file"),
    ]
    (tmp_path / "nojson").mkdir()
    shutil.copy(dataset / "trajectory.h5", tmp_path / "nojson" / "trajectory.h5")
    cases.append((tmp_path / "nojson" / "trajectory.h5", "missing; ManiSkill's replay needs"))
    for h5, words in cases:
        res = run(["replay", "--traj-path", str(h5), "-o", "state"], tmp_path, check=False)
        err = res.stderr.strip().splitlines()
        assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
        assert words in err[-1] and str(h5.parent) in err[-1], err

    # a dataset of a copied scene whose mug mesh then changed: replay says so first
    layout = scene_copy / "layouts" / "default.json"

    def to_copy(m):
        m["env_info"]["env_kwargs"]["layout_file"] = str(layout)

    h5 = copy("changed", to_copy)
    mesh = scene_copy / "assets" / "mug" / "mesh" / "mug.obj"
    mesh.write_text(mesh.read_text() + "\n# edited\n")
    res = run(["replay", "--traj-path", str(h5), "-o", "state", "-n", "1"], tmp_path, check=False)
    assert "or its asset files changed since this dataset was recorded" in res.stdout


def test_two_collect_runs_of_the_same_seeds_give_the_same_actions(tmp_path):
    """Plans are seeded (solvers/motion.py): two runs of one command, each in processes of
    its own, write the same actions byte for byte. On the round table, seed 3 turns the hand
    at the goal (its wrist is near its limit)."""
    layout = DATA / "layouts" / "round_table.json"
    for out in ("a", "b"):
        run(["collect", "--layout", str(layout), "--num", "3", "--seed", "3", "--out", out],
            tmp_path)  # fmt: skip
    files = [tmp_path / out / "round_table" / "trajectory.h5" for out in ("a", "b")]
    with h5py.File(files[0]) as a, h5py.File(files[1]) as b:
        assert sorted(a) == sorted(b) == ["traj_0", "traj_1", "traj_2"]
        for key in a:
            assert a[key]["actions"][:].tobytes() == b[key]["actions"][:].tobytes(), key
            assert len(a[key]["actions"]) > 80  # a whole pick and place (84-134 steps)


def test_fixed_hand_demos_convert_to_position_only_control(tmp_path):
    """`collect --fixed-hand` says so in the dataset's source_desc, and `replay -c
    pd_ee_delta_pos` keeps its demo: round_table seed 115, whose demo without the flag turns
    the hand and does not convert (tests/datasets/test_ee_actions.py)."""
    layout = DATA / "layouts" / "round_table.json"
    args = ["--num", "1", "--seed", "115", "--only-success", "--fixed-hand", "--out", "out"]
    res = run(["collect", "--layout", str(layout), *args], tmp_path, check=False)
    assert "round_table.json: 1 demonstrations (1/1 successful" in res.stdout, res.stdout[-2000:]
    traj = tmp_path / "out" / "round_table" / "trajectory.h5"
    meta = json.loads(traj.with_suffix(".json").read_text())
    assert "collect --fixed-hand" in meta["source_desc"]
    res = run(["replay", "--traj-path", str(traj), "-c", "pd_ee_delta_pos"], tmp_path)
    assert "1/1=" in res.stdout, res.stdout[-2000:]


@pytest.mark.parametrize("mode", ["pd_ee_delta_pos", "pd_joint_vel"])
def test_native_control_mode_datasets_replay_in_maniskill(tmp_path, mode):
    """`collect --control-mode` records the mode's actions (no conversion afterwards); the
    dataset says so, and ManiSkill's own replay_trajectory, replaying the actions alone (no
    env states), keeps every demo."""
    args = ["--num", "2", "--seed", "3", "--only-success", "--control-mode", mode, "--out", "out"]
    res = run(["collect", *args], tmp_path, check=False)
    assert "default.json: 2 demonstrations (2/2 successful" in res.stdout, res.stdout[-2000:]
    traj = tmp_path / "out" / "default" / "trajectory.h5"
    meta = json.loads(traj.with_suffix(".json").read_text())
    assert meta["env_info"]["env_kwargs"]["control_mode"] == mode
    assert "control mode's actions" in meta["source_desc"]
    dims = {"pd_ee_delta_pos": 4, "pd_joint_vel": 8}[mode]
    with h5py.File(traj) as f:
        for key in f:
            actions = f[key]["actions"][:]
            assert actions.shape[1] == dims and np.abs(actions).max() <= 1.0
    replay = [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
              str(traj), "-b", "physx_cpu"]  # fmt: skip
    res = subprocess.run(replay, cwd=tmp_path, env=ENV, capture_output=True, text=True,
                         timeout=600)  # fmt: skip
    assert "Replayed 2 episodes, 2/2=100.00% demos saved" in res.stdout, res.stdout + res.stderr
    if mode == "pd_ee_delta_pos":  # ManiSkill's converter takes pd_joint_pos or delta actions
        res = run(["replay", "--traj-path", str(traj), "-c", "pd_joint_vel"], tmp_path, False)
        assert res.returncode == 1 and "Traceback" not in res.stdout + res.stderr
        assert "its actions are pd_ee_delta_pos" in res.stdout + res.stderr
        assert "collect --control-mode pd_joint_vel" in res.stdout + res.stderr
