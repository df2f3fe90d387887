"""Nothing floats, nothing sinks: on tables and in bowls of several shapes -- collision written
as one object of pieces, as one closed concave object (CoACD's parts), or one object per part
(EmbodiedGen's form) -- every object rests where a camera sees the table, by its visual mesh;
the table's top stands where its file says; generated layouts put objects on the visual top."""

import json
import shutil

import gymnasium as gym
import numpy as np
import pytest
import torch
import trimesh
from conftest import DATA, DEFAULT_LAYOUT
from mani_skill.utils.structs.pose import Pose
from scipy.spatial.transform import Rotation
from shapes import (
    BOWL_FLOOR,
    bowl_shell,
    bowl_wedges,
    round_table_pieces,
    table_pieces,
    write_asset,
)

import embodied_envs  # noqa: F401
from embodied_envs.cli.main import main
from embodied_envs.layout import LayoutPose, load_layout, parse_urdf
from embodied_envs.layout import collision as col
from embodied_envs.registration import CONTROL_FREQ

REST = 2e-3  # m: a resting object's visual lowest point from the visual surface it stands on
SHIPPED = ("background", "can", "cracker_box", "block", "table", "bowl")
# (table, bowl) asset folders of each scene: pieces in one object, CoACD's parts, EmbodiedGen's
SCENES = {
    "table_of_pieces": ("piece_table", "one_object_bowl"),
    "round_table_of_pieces": ("round_piece_table", "bowl_of_touching_parts"),
    "embodiedgen_form": ("table", "bowl"),
}
VARIANTS = 30  # layouts generated on the table of pieces


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The test assets (made here) and the shipped ones, and a layout per scene: a can, a
    cracker box and a bowl on the table, a block in the bowl. Decompositions go to a cache
    of this module's own."""
    root = tmp_path_factory.mktemp("resting")
    assets = root / "assets"
    for name in SHIPPED:
        shutil.copytree(DATA / "assets" / name, assets / name)
    write_asset(assets, "piece_table", table_pieces())
    write_asset(assets, "round_piece_table", round_table_pieces())
    write_asset(assets, "one_object_bowl", [bowl_shell()], mass=0.25)
    write_asset(assets, "bowl_of_touching_parts", bowl_wedges(), mass=0.25)
    base = json.loads(DEFAULT_LAYOUT.read_text())
    layouts = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(col.CACHE_ENV, str(root / "cache"))
        mp.delenv(col.OPT_OUT_ENV, raising=False)
        col._convex_collision.cache_clear()
        for scene, (table, bowl) in SCENES.items():
            d = json.loads(json.dumps(base))
            d["tree"]["table"] = [["can", "ON"], ["cracker_box", "ON"], ["bowl", "ON"]]
            d["tree"]["bowl"] = [["block", "IN"]]
            d["relation"]["distractor_objs"] = ["cracker_box", "bowl", "block"]
            d["objs_mapping"] = {k: v for k, v in d["objs_mapping"].items() if k != "mug"}
            d["objs_mapping"]["block"] = "distractor_objs"
            d["assets"] = {n: f"../assets/{n}" for n in ("background", "can", "cracker_box")}
            d["assets"] |= {"table": f"../assets/{table}", "bowl": f"../assets/{bowl}"}
            d["assets"]["block"] = "../assets/block"
            d["position"].pop("mug")
            d["position"]["block"] = d["position"]["bowl"]
            d["objs_desc"] = {}
            src = root / "src" / f"{scene}.json"
            src.parent.mkdir(exist_ok=True)
            src.write_text(json.dumps(d))
            out = root / "layouts" / scene
            num = VARIANTS if scene == "table_of_pieces" else 1
            assert main(["layout", "generate", str(src), "--num", str(num), "--out", str(out)]) == 0
            layouts[scene] = sorted(out.glob("*.json"))
        yield layouts
    col._convex_collision.cache_clear()


def visual_link(layout, node) -> np.ndarray:
    """A node's visual vertices in its actor frame (Z-up)."""
    spec = parse_urdf(layout.urdf_path(node))
    mesh = trimesh.load(spec.visual.path, force="mesh", process=False, skip_materials=True)
    return spec.visual.to_link_frame(mesh.vertices)


def world(points: np.ndarray, raw_pose) -> np.ndarray:
    """Points of an actor frame in the world, the actor at ManiSkill's ``p, q (wxyz)``."""
    p, q = np.asarray(raw_pose[:3]), np.asarray(raw_pose[3:])
    return points @ Rotation.from_quat([*q[1:], q[0]]).as_matrix().T + p


def test_generated_variants_stand_on_the_visual_top(scenes):
    files = scenes["table_of_pieces"]
    assert len(files) == VARIANTS
    for f in files:
        layout = load_layout(f)
        top = layout.pose("table").transform_points(visual_link(layout, "table"))
        assert top[:, 2].min() == pytest.approx(0.0, abs=REST), f"{f}: the table floats"
        for node in ("can", "cracker_box", "bowl"):
            low = layout.pose(node).transform_points(visual_link(layout, node))[:, 2].min()
            assert low == pytest.approx(top[:, 2].max(), abs=REST), f"{f}: {node}"


@pytest.mark.parametrize("scene", list(SCENES))
def test_after_a_second_of_idle_steps_everything_rests_on_what_the_camera_sees(scenes, scene):
    layout_file = scenes[scene][0]
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout_file))
    try:
        env.reset(seed=7)
        u = env.unwrapped
        layout = u.layouts[0]
        actors = u.env_actors["env0"]
        zero = np.zeros(env.action_space.shape, dtype=np.float32)

        def settle():
            for _ in range(CONTROL_FREQ):  # one second
                env.step(zero)

        def visual(node):
            return world(visual_link(layout, node), actors[node].pose.raw_pose[0].tolist())

        settle()
        # the table's top where its file says: its pose there, its visual mesh's top
        table = visual("table")
        file_top = (
            LayoutPose.from_layout(layout.position["table"])
            .transform_points(visual_link(layout, "table"))[:, 2]
            .max()
        )
        assert table[:, 2].max() == pytest.approx(file_top, abs=REST)
        assert table[:, 2].min() == pytest.approx(0.0, abs=REST), "the table floats or sinks"
        for node in ("can", "cracker_box", "bowl"):
            low = visual(node)[:, 2].min()
            assert low == pytest.approx(table[:, 2].max(), abs=REST), node
        # a block let go over the bowl's centre rests on the bowl's floor
        bowl = actors["bowl"].pose.p[0]
        bowl_low = visual("bowl")[:, 2].min()
        p = torch.tensor([[float(bowl[0]), float(bowl[1]), bowl_low + BOWL_FLOOR + 0.01]])
        actors["block"].set_pose(Pose.create_from_pq(p, torch.tensor([[1.0, 0, 0, 0]])))
        settle()
        low = visual("block")[:, 2].min()
        assert low == pytest.approx(visual("bowl")[:, 2].min() + BOWL_FLOOR, abs=REST)
    finally:
        env.close()
