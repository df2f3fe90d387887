"""Layout sets and asset pools (issue 18): draws, envs, per-env rooms, datasets across layouts."""

import collections
import json
import os
import shutil
import subprocess
import sys

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch
from conftest import DATA
from placement_checks import check_constraints
from scene_sets import make_scene_set

import embodied_envs  # noqa: F401
from embodied_envs.layout import LayoutError, LayoutPose
from embodied_envs.layout.placement import node_geometry, place
from embodied_envs.layout.sets import LayoutSet, layout_files, spec_name
from embodied_envs.registration import ENTRY_ID, ENV_ID

CLI = [sys.executable, "-m", "embodied_envs.cli.main"]
ENV = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    return make_scene_set(tmp_path_factory.mktemp("scenes"), DATA)


def first_seeds(layout_set: LayoutSet, env: int = 0, limit: int = 200) -> dict:
    """The first seed that draws each layout file."""
    out = {}
    for seed in range(limit):
        out.setdefault(layout_set.draw(seed, env).source, seed)
    return out


def test_a_folder_a_glob_and_a_list_name_the_same_set(scenes, tmp_path):
    folder = scenes["set"]
    files = [folder / "box.json", folder / "default.json", folder / "round_table.json"]
    assert layout_files(folder) == files, "a folder's *.json, sorted by name"
    assert layout_files(str(folder / "*.json")) == files
    assert layout_files([str(f) for f in files]) == files
    assert layout_files((files[2], files[0], files[2])) == [files[2], files[0]], "order, once"
    assert spec_name(folder) == "set" and spec_name(str(folder / "*.json")) == "set"
    assert spec_name(files[0]) == "box"
    seeds = range(50)
    draws = [
        [LayoutSet.load(spec).draw(s, 0).source for s in seeds]
        for spec in (folder, str(folder / "*.json"), [str(f) for f in files])
    ]
    assert draws[0] == draws[1] == draws[2]
    (tmp_path / "empty").mkdir()
    for spec, words in (
        ([], "an empty list names no layout"),
        (tmp_path / "empty", "holds no *.json layout file"),
        (str(tmp_path / "no_*.json"), "the glob matches no layout file"),
        ([3], "3 is not a path"),
        (tmp_path / "missing.json", "layout file does not exist"),
    ):
        with pytest.raises(LayoutError) as e:
            LayoutSet.load(spec)
        assert words in str(e.value), (spec, str(e.value))


def test_draws_cover_every_layout_evenly_and_repeat_by_seed(scenes):
    layout_set = LayoutSet.load(scenes["set"])
    counts = collections.Counter(layout_set.draw(s, 0).source.name for s in range(3000))
    assert set(counts) == {"box.json", "default.json", "round_table.json"}
    for name, n in counts.items():
        assert 0.3 <= n / 3000 <= 0.367, (name, n)  # 1/3 within ~4 standard deviations
    same = [layout_set.draw(s, 0).source == layout_set.draw(s, 0).source for s in range(50)]
    assert all(same)
    # the envs of one configuration draw independently
    pairs = collections.Counter(
        (layout_set.draw(s, 0).source.name, layout_set.draw(s, 1).source.name) for s in range(900)
    )
    assert len(pairs) == 9 and min(pairs.values()) > 60
    single = LayoutSet.load(DATA / "layouts" / "default.json")
    assert not single.varies and single.draw(7, 0) is single.layouts[0], "nothing drawn"


def target_extent(u) -> np.ndarray:
    """The graded target's collision mesh extent in its own frame (trimesh): XY sorted, then
    Z; the merged target ``u.obj`` is env 0's actor of the drawn layout's target."""
    actor = u.env_actors["env0"][u.layouts[0].target_node]
    assert torch.equal(u.obj.per_scene_id, actor.per_scene_id)
    mesh = actor.get_first_collision_mesh(to_world_frame=False)
    return np.r_[np.sort(mesh.extents[:2]), mesh.extents[2]]


def test_reconfigurations_follow_the_draw(scenes):
    """Seeded reconfigurations of a CPU env visit every layout; the instruction, the graded
    target's geometry and the starts follow the drawn layout; the same seed draws the same."""
    layout_set = LayoutSet.load(scenes["set"])
    seeds = first_seeds(layout_set)
    assert len(seeds) == 3
    env = gym.make(ENV_ID, layout_file=str(scenes["set"]))
    u = env.unwrapped
    try:
        for source, seed in seeds.items():
            env.reset(seed=seed, options=dict(reconfigure=True))
            drawn = u.layouts[0]
            assert drawn.source == source
            assert u.instructions == [drawn.instruction]
            want = node_geometry(drawn, drawn.target_node)
            span = want.vertices.ptp(0)
            np.testing.assert_allclose(target_extent(u), [*np.sort(span[:2]), span[2]], atol=2e-3)
            start = u.obj.pose.raw_pose.clone()
            assert check_constraints(episode_layout_of(u)) == []
            env.reset(seed=seed, options=dict(reconfigure=True))
            assert u.layouts[0].source == source
            assert torch.equal(u.obj.pose.raw_pose, start), "the same seed, the same start"
        box = next(s for s in seeds if s.name == "box.json")
        env.reset(seed=seeds[box], options=dict(reconfigure=True))
        assert u.instructions == ["Pick up a red cracker box with a yellow top and hold it at "
                                  "the goal."]  # fmt: skip
        assert env.spec.kwargs["layout_file"] == [str(f) for f in layout_set.files]
    finally:
        env.close()


def episode_layout_of(u):
    """Env 0's configuration with its objects where they stand now."""
    poses = {}
    layout = u.layouts[0]
    for node in layout.object_nodes():
        if node == layout.context:
            continue
        x, y, z, qw, qx, qy, qz = u.env_actors["env0"][node].pose.raw_pose[0].tolist()
        poses[node] = LayoutPose.from_layout([x, y, z - u.objs_z_offset, qx, qy, qz, qw])
    return layout.with_poses(poses)


def green_fraction(frame: torch.Tensor) -> float:
    f = frame[0].int()
    return float(((f[..., 1] > f[..., 0] + 60) & (f[..., 1] > f[..., 2] + 60)).float().mean())


def test_each_layout_composites_its_own_room(scenes):
    """Hybrid frames show the drawn layout's splat: the green room for box.json only."""
    layout_set = LayoutSet.load(scenes["set"])
    seeds = first_seeds(layout_set)
    env = gym.make(ENV_ID, layout_file=str(scenes["set"]), render_mode="hybrid")
    u = env.unwrapped
    try:
        for source, seed in seeds.items():
            env.reset(seed=seed, options=dict(reconfigure=True))
            green = green_fraction(env.render())
            assert u.hybrid.rooms == [u.layouts[0].gs_model_path()]
            if source.name == "box.json":
                assert green > 0.3, green
            else:
                assert green < 0.02, (source.name, green)
    finally:
        env.close()


def test_identical_views_of_a_room_are_rendered_once(scenes):
    """Backgrounds are rendered per (room, camera in the room's frame): envs that share both
    share the render, and a different room is rendered on its own."""
    from embodied_envs.config import SPLAT_Y_UP_TO_Z_UP
    from embodied_envs.envs.hybrid import HybridRenderer
    from embodied_envs.splat import PinholeCamera

    shipped = DATA / "assets" / "background" / "gs_model.ply"
    green = scenes["root"] / "assets" / "background_green" / "gs_model.ply"
    hybrid = HybridRenderer({shipped: "a", green: "b"}, SPLAT_Y_UP_TO_Z_UP)
    cam = PinholeCamera.look_at((0.6, 0.0, 1.1), (0, 0, 0.9), (0, 0, 1), 40, 32)
    same = LayoutPose.from_xyz_yaw((0, 0, 0), 0.4)
    other = LayoutPose.from_xyz_yaw((0, 0, 0), 1.9)
    rgb, depth = hybrid.render_backgrounds(
        [cam] * 4, [same, same, other, same], [shipped, shipped, shipped, green]
    )
    assert hybrid.renders == 3, "envs 0 and 1 share one render"
    assert torch.equal(rgb[0], rgb[1]) and not torch.equal(rgb[0], rgb[2])
    assert green_fraction(rgb[3:4]) > 0.3 and green_fraction(rgb[0:1]) < 0.02


def test_an_asset_pool_draws_its_members(scenes):
    """A pool of three assets: reconfigurations draw every member; the target's geometry and
    the instruction follow the member; the same seed draws the same member."""
    layout_set = LayoutSet.load(scenes["pooled"])
    assert layout_set.pools[0] == {"can": [f"../assets/pool/{m}" for m in
                                           ("bottle", "can", "cracker_box")]}  # fmt: skip
    counts = collections.Counter(layout_set.draw(s, 0).assets["can"] for s in range(600))
    assert len(counts) == 3 and min(counts.values()) > 150
    env = gym.make(ENV_ID, layout_file=str(scenes["pooled"]))
    u = env.unwrapped
    try:
        seen = {}
        for seed in range(12):
            env.reset(seed=seed, options=dict(reconfigure=True))
            member = u.layouts[0].assets["can"].split("/")[-1]
            assert member == layout_set.draw(seed, 0).assets["can"].split("/")[-1]
            assert (
                u.instructions[0] == f"Pick up {member.replace('_', ' ')} and hold it at the goal."
            )
            seen[member] = target_extent(u)
            span = node_geometry(u.layouts[0], "can").vertices.ptp(0)
            np.testing.assert_allclose(seen[member], [*np.sort(span[:2]), span[2]], atol=2e-3)
            assert check_constraints(episode_layout_of(u)) == []
        assert set(seen) == {"bottle", "can", "cracker_box"}
        extents = list(seen.values())
        assert all(
            np.abs(a - b).max() > 0.01 for i, a in enumerate(extents) for b in extents[i + 1 :]
        )
    finally:
        env.close()
    with pytest.raises(LayoutError, match="asset pools need replace_objs=True"):
        gym.make(ENV_ID, layout_file=str(scenes["pooled"]), replace_objs=False)


def test_a_bad_pool_member_is_named(scenes, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(scenes["root"] / "assets", root / "assets", symlinks=True)
    shutil.copytree(scenes["root"] / "pooled", root / "pooled")
    urdf = root / "assets" / "pool" / "bottle" / "bottle.urdf"
    urdf.write_text("<robot name='bottle'><link name='x'>")  # truncated
    for problem in (
        lambda: LayoutSet.load(root / "pooled" / "pool.json"),
        lambda: gym.make(ENV_ID, layout_file=str(root / "pooled")),
    ):
        with pytest.raises(LayoutError) as e:
            problem()
        assert "bottle.urdf" in str(e.value) and 'assets["can"]' in str(e.value)
    res = subprocess.run(
        [*CLI, "layout", "validate", str(root / "pooled")],
        env=ENV, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 1 and "FAIL" in res.stdout and "pool/bottle/bottle.urdf" in res.stdout


def test_async_vector_env_on_a_set(scenes):
    """Two worker processes (forkserver: a fork of a process holding SAPIEN hangs), each its
    own seed: each draws the layout its seed draws."""
    layout_set = LayoutSet.load(scenes["set"])
    by_layout = first_seeds(layout_set)
    seeds = [by_layout[layout_set.files[0]], by_layout[layout_set.files[2]]]
    envs = gym.make_vec(
        ENTRY_ID, num_envs=2, vectorization_mode="async", layout_file=str(scenes["set"]),
        obs_mode="state", vector_kwargs=dict(context="forkserver"),
    )  # fmt: skip
    try:
        obs, _ = envs.reset(seed=seeds, options=dict(reconfigure=True))
        instructions = envs.get_attr("instructions")
        want = [[layout_set.draw(s, 0).instruction] for s in seeds]
        assert [list(x) for x in instructions] == want
        assert want[0] != want[1]
        assert obs.shape[0] == 2 and np.isfinite(obs).all()
        _, reward, *_ = envs.step(np.zeros((2, *envs.single_action_space.shape)))
        assert np.isfinite(np.asarray(reward, dtype=float).reshape(2)).all()
    finally:
        envs.close()


@pytest.fixture(scope="module")
def mixed_dataset(scenes, tmp_path_factory):
    """Demonstrations collected over the three-layout set (one dataset), seeds chosen to
    draw every layout."""
    layout_set = LayoutSet.load(scenes["set"])
    seeds = first_seeds(layout_set)
    first = max(seeds.values())
    while len({layout_set.draw(s, 0).source for s in range(first - 3, first + 1)}) < 3:
        first += 1
    work = tmp_path_factory.mktemp("mixed")
    res = subprocess.run(
        [*CLI, "collect", "--layout", str(scenes["set"]), "--num", "4", "--seed",
         str(first - 3), "--out", "out"],
        cwd=work, env=ENV, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert "set (3 layouts): 4 demonstrations" in res.stdout, res.stdout + res.stderr
    return work / "out" / "set", layout_set, list(range(first - 3, first + 1))


def test_a_mixed_dataset_records_each_layout_and_replays_exactly(mixed_dataset, tmp_path):
    """ManiSkill's own replay_trajectory (not our wrapper) re-creates every episode in its
    layout: replayed actor states equal the recorded ones."""
    folder, layout_set, seeds = mixed_dataset
    meta = json.loads((folder / "trajectory.json").read_text())
    assert meta["env_info"]["env_id"] == ENTRY_ID
    assert meta["env_info"]["env_kwargs"]["layout_file"] == [str(f) for f in layout_set.files]
    episodes = meta["episodes"]
    assert [e["episode_seed"] for e in episodes] == seeds
    for e in episodes:
        drawn = layout_set.draw(e["episode_seed"], 0)
        assert e["layout_file"] == str(drawn.source) and e["instruction"] == drawn.instruction
        assert e["reset_kwargs"]["options"] == {"reconfigure": True}
    assert len({e["layout_file"] for e in episodes}) == 3
    work = tmp_path / "data"
    shutil.copytree(folder, work)
    subprocess.run(
        [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
         str(work / "trajectory.h5"), "-o", "state", "--save-traj", "--allow-failure"],
        cwd=tmp_path, env=ENV, check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    out = next(work.glob("trajectory.state.*.h5"))
    with h5py.File(work / "trajectory.h5") as a, h5py.File(out) as b:
        for e in episodes:
            key = f"traj_{e['episode_id']}"
            rec, rep = a[key]["env_states/actors"], b[key]["env_states/actors"]
            drawn = layout_set.draw(e["episode_seed"], 0)
            nodes = {n for n in drawn.object_nodes() if n != drawn.context}
            assert set(rec) == nodes | {"goal_site"}, "each episode holds its own layout's objects"
            for actor in rec:
                np.testing.assert_allclose(rep[actor][:], rec[actor][:], atol=1e-5)


def test_a_merge_of_different_layouts_is_refused(mixed_dataset, tmp_path):
    """A dataset whose episodes name layouts its env_kwargs do not hold (what merging two
    layouts' datasets makes) is refused in one line, before replaying in the wrong scene."""
    folder, layout_set, _ = mixed_dataset
    work = tmp_path / "data"
    shutil.copytree(folder, work)
    meta = json.loads((work / "trajectory.json").read_text())
    meta["env_info"]["env_kwargs"]["layout_file"] = str(layout_set.files[1])
    (work / "trajectory.json").write_text(json.dumps(meta))
    res = subprocess.run(
        [*CLI, "replay", "--traj-path", str(work / "trajectory.h5")],
        env=ENV, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode != 0
    text = res.stdout + res.stderr
    assert (
        "merged datasets of different layouts" in text and "Fix: collect over a layout set" in text
    )


def test_the_lerobot_export_carries_each_episodes_instruction(mixed_dataset, tmp_path):
    import pandas as pd

    folder, layout_set, seeds = mixed_dataset
    work = tmp_path / "data"
    shutil.copytree(folder, work)
    subprocess.run(
        [*CLI, "replay", "--traj-path", str(work / "trajectory.h5"), "-o", "rgb", "--save-traj",
         "--allow-failure"],
        cwd=tmp_path, env=ENV, check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    rgb = next(work.glob("trajectory.rgb.*.h5"))
    subprocess.run(
        [*CLI, "lerobot", "--traj-path", str(rgb), "--output-dir", str(tmp_path / "lr"),
         "--image-size", "64"],
        cwd=tmp_path, env=ENV, check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    want = [layout_set.draw(s, 0).instruction for s in seeds]
    tasks = pd.read_parquet(tmp_path / "lr" / "meta" / "tasks.parquet")
    assert list(tasks.index) == list(dict.fromkeys(want)) and len(tasks) == 3
    frames = pd.concat(pd.read_parquet(p) for p in (tmp_path / "lr" / "data").rglob("*.parquet"))
    with h5py.File(rgb) as f:
        order = [int(k[5:]) for k in f.keys() if k.startswith("traj_")]
    for index, episode_id in enumerate(order):
        rows = frames[frames["episode_index"] == index]
        assert set(rows["task"]) == {want[episode_id]}
        assert set(rows["task_index"]) == {list(tasks.index).index(want[episode_id])}
    info = json.loads((tmp_path / "lr" / "meta" / "info.json").read_text())
    assert info["total_tasks"] == 3


def test_parallel_envs_need_as_many_objects_in_every_layout(scenes):
    """GPU sub-scenes merge objects slot by slot: a set whose layouts hold different numbers
    of objects is refused for num_envs > 1 before anything is built (checked on CPU through
    the same rule the GPU path runs)."""
    from embodied_envs.scene.layout_scene import scene_slots

    layout_set = LayoutSet.load(scenes["set"])
    with pytest.raises(LayoutError, match="must hold as many objects each"):
        scene_slots(list(layout_set.layouts))
    same = LayoutSet.load(scenes["same_count"])
    names = same.layouts[0].object_nodes()
    assert scene_slots(list(same.layouts)) == [{n: n for n in names}] * 3, "same nodes: names"
    four = LayoutSet.load(scenes["four"])
    slots = scene_slots(list(four.layouts))
    assert [s[x.target_node] for s, x in zip(slots, four.layouts, strict=True)] == ["target"] * 3
    assert [s[x.context] for s, x in zip(slots, four.layouts, strict=True)] == ["context"] * 3
    assert {frozenset(s.values()) for s in slots} == {
        frozenset({"context", "target", "object1", "object2"})
    }


@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_heterogeneous_episode_draws_are_batched_per_layout(scenes, backend):
    """Six envs over three layouts with different nodes and tables (as on the GPU): one
    sampler per layout, starts keyed by slot, each env's start
    meets its own layout's constraints, a partial reset draws for its envs only, and a
    seeded draw is the same as drawing that env alone."""
    from mani_skill.envs.utils.randomization.batched_rng import BatchedRNG

    from embodied_envs.layout import GoalRegion, PlacementLimits
    from embodied_envs.layout.placement.episode import EpisodeSampler
    from embodied_envs.scene.layout_scene import SceneEpisodes, scene_slots

    four = LayoutSet.load(scenes["four"])
    layouts = [place(four.layouts[k % 3], 100 + k) for k in range(6)]
    slots = scene_slots(layouts)
    groups = [[0, 3], [1, 4], [2, 5]]
    samplers = [
        EpisodeSampler([layouts[i] for i in g], PlacementLimits(), GoalRegion(),
                       env_ids=torch.tensor(g), backend=backend)
        for g in groups
    ]  # fmt: skip
    episodes = SceneEpisodes.of(samplers, [slots[g[0]] for g in groups], 6)
    assert torch.equal(episodes.top_z, torch.tensor([float(samplers[k % 3].top_z[k // 3])
                                                     for k in range(6)]))  # fmt: skip
    rngs = BatchedRNG.from_seeds(list(range(6)))
    episodes.reseeded(0, torch.arange(6), False)
    start = episodes.draw(torch.arange(6), rngs)
    assert set(start.objects) == {"target", "object1", "object2"}
    for k, layout in enumerate(layouts):
        poses = {
            node: LayoutPose.from_layout(
                [
                    *start.objects[slot][k, :3].tolist(),
                    *start.objects[slot][k, [4, 5, 6, 3]].tolist(),
                ]
            )
            for node, slot in slots[k].items()
            if slot != "context"
        }
        assert check_constraints(layout.with_poses(poses)) == [], k
    # a partial reset of envs 1 and 4 (one layout) and 5: the same as each alone, fresh RNGs
    again = BatchedRNG.from_seeds(list(range(6)))
    episodes.reseeded(0, torch.arange(6), False)
    part = episodes.draw(torch.tensor([1, 4, 5]), again)
    for slot, pose in part.objects.items():
        torch.testing.assert_close(pose, start.objects[slot][[1, 4, 5]])
    torch.testing.assert_close(part.goal, start.goal[[1, 4, 5]])


def test_demo_shows_the_layout_each_env_draws(scenes, tmp_path):
    layout_set = LayoutSet.load(scenes["set"])
    seed = next(s for s in range(200) if len({layout_set.draw(s, k).source for k in (0, 1)}) == 2)
    subprocess.run(
        [*CLI, "demo", "--layout", str(scenes["set"]), "--num-envs", "2", "--seed", str(seed),
         "--render-mode", "rgb_array", "--image-hw", "48", "64", "--frame-every", "10",
         "--out", str(tmp_path / "demo")],
        env=ENV, check=True, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    for k, path in enumerate(summary["layouts"]):
        drawn = layout_set.draw(seed, k)
        shown = json.loads(open(path).read())
        assert shown["relation"]["manipulated_objs"] == drawn.manipulated_objs, k
        assert set(shown["assets"]) == set(drawn.assets), k
    assert summary["layouts"][0] == str(layout_set.draw(seed, 0).source), "env 0: the file"
    assert (tmp_path / "demo" / "episode_000.mp4").stat().st_size > 1000
