"""The support tree, walked once (``layout/placement/tree.py``) for both placements: objects
standing on other objects are placed on them, per configuration and per episode, and a top too
small to stand on is refused by one error, the same from either placement."""

import json
import math

import numpy as np
import pytest
import torch
from conftest import DATA, DEFAULT_LAYOUT, write_layout
from placement_checks import world_points
from shapely.geometry import MultiPoint

from embodied_envs.layout import LayoutPose, PlacementError, PlacementLimits, load_layout
from embodied_envs.layout.placement import place, support_tree
from embodied_envs.layout.placement.episode import EpisodeSampler


def variant(tmp_path, source, change, name="layout.json"):
    """A shipped layout with its tree changed by ``change(tree)`` (file poses not checked:
    placement re-draws them)."""
    data = json.loads(source.read_text())
    data["assets"] = {k: str((source.parent / v).resolve()) for k, v in data["assets"].items()}
    change(data["tree"])
    return load_layout(write_layout(tmp_path, data, name), check_poses=False)


def can_in_bowl(tree):
    tree["table"].remove(["can", "ON"])
    tree["bowl"] = [["can", "IN"]]


def footprint(layout, node):
    return MultiPoint(world_points(layout, node)[:, :2].tolist()).convex_hull


def nested_violations(layout, lim: PlacementLimits, z_tol: float) -> list[str]:
    """The can in the bowl, checked with shapely on the collision vertices: its footprint in
    the bowl's top shrunk by the hull margin, resting on that top, clear of every other
    object and of the robot base's square, within the robot's reach."""
    bad = []
    bowl = world_points(layout, "bowl")
    top_z = bowl[:, 2].max()
    top = MultiPoint(bowl[bowl[:, 2] >= top_z - lim.top_band][:, :2].tolist()).convex_hull
    can = world_points(layout, "can")
    foot = MultiPoint(can[:, :2].tolist()).convex_hull
    if not top.buffer(-lim.hull_margin + 1e-4).contains(foot):
        bad.append("the can's footprint leaves the bowl's shrunk top")
    if abs(can[:, 2].min() - top_z) > z_tol:
        bad.append(f"the can does not rest on the bowl's top ({can[:, 2].min() - top_z:+.4f})")
    robot = layout.pose(layout.robot)
    h = lim.robot_footprint / 2
    c, s = math.cos(robot.yaw), math.sin(robot.yaw)
    corners = [(robot.p[0] + c * a - s * b, robot.p[1] + s * a + c * b)
               for a in (-h, h) for b in (-h, h)]  # fmt: skip
    others = {n: footprint(layout, n) for n in ("cracker_box", "mug")}
    others["robot"] = MultiPoint(corners).convex_hull
    for name, other in others.items():
        if foot.distance(other) < lim.clearance - 1e-4:
            bad.append(f"the can is closer than the clearance to {name}")
    d = math.dist(layout.pose("can").p[:2], robot.p[:2])
    if not lim.reach_min < d < lim.reach_max:
        bad.append(f"the can is {d:.3f} m from the robot")
    return bad


def test_the_walk_orders_supports_first_and_keeps_objects_clear_of_all_but_their_supports(
    tmp_path,
):
    layout = variant(tmp_path, DEFAULT_LAYOUT, can_in_bowl)
    tree = support_tree(layout, PlacementLimits())
    order = [(it.node, it.parent) for it in tree.items]
    # breadth first from the table (larger footprints first), then what stands on the bowl
    assert order == [("bowl", "table"), ("mug", "table"), ("cracker_box", "table"),
                     ("can", "bowl")]  # fmt: skip
    # obstacles: 0 the robot base, 1 + j item j; the can keeps clear of all but the bowl
    assert [it.avoid for it in tree.items] == [(0,), (0, 1), (0, 1, 2), (0, 2, 3)]
    assert [it.supports for it in tree.items] == [True, False, False, False]
    assert [it.manipulated for it in tree.items] == [False, False, False, True]
    assert tree.items[0].top.shrunk is not None


def test_an_object_in_a_bowl_is_placed_in_it_per_configuration_and_per_episode(tmp_path):
    lim = PlacementLimits()
    layout = variant(tmp_path, DEFAULT_LAYOUT, can_in_bowl)
    configs = []
    for seed in range(20):
        try:
            configs.append(place(layout, seed))
        except PlacementError as e:  # the bowl out of reach: the can cannot stand in it
            assert e.node == "can" and "robot" in e.constraint, e
    assert len(configs) >= 10
    for k, config in enumerate(configs):
        assert nested_violations(config, lim, 1e-6) == [], k
    sampler = EpisodeSampler(configs[:4], lim)
    env_idx, keys = torch.arange(4).repeat(10), torch.arange(40) * 7919
    with pytest.warns(UserWarning, match="no valid arrangement"):  # the fallbacks below
        starts = sampler.objects(env_idx, keys)
    for row, env in enumerate(env_idx.tolist()):
        poses = {}
        for node, raw in starts.items():
            x, y, z, qw, qx, qy, qz = raw[row].tolist()
            poses[node] = LayoutPose.from_layout([x, y, z, qx, qy, qz, qw])
        drawn = configs[env].with_poses(poses)
        assert nested_violations(drawn, lim, 1e-4) == [], row  # float32 draws
    # an episode whose bowl lands out of reach keeps its configuration (a fallback)
    kept = [r for r in range(40) if np.allclose(starts["can"][r], sampler.fallback["can"][r % 4])]
    assert len(kept) == sampler.fallbacks < 20
    offsets = {tuple(np.round((starts["can"][r, :2] - starts["bowl"][r, :2]).numpy(), 4))
               for r in range(40) if r not in kept}  # fmt: skip
    assert len(offsets) == 40 - len(kept), "the can stands anywhere in the bowl, drawn anew"


@pytest.mark.parametrize("case", ["object", "context"])
def test_a_top_too_small_is_refused_by_one_error_from_either_placement(tmp_path, case):
    """Nothing fits on the bottle's top (it vanishes when shrunk by the hull margin), nor on
    a table shrunk by half a metre on every side: place() and the per-episode sampler raise
    the same error, naming the file, what cannot stand, the support and the limit."""
    if case == "object":

        def banana_on_bottle(tree):
            tree["round_table"].remove(["banana", "ON"])
            tree["bottle"] = [["banana", "ON"]]

        layout = variant(tmp_path, DATA / "layouts" / "round_table.json", banana_on_bottle)
        limits, child, support = PlacementLimits(), "banana", "bottle"
    else:
        layout = variant(tmp_path, DEFAULT_LAYOUT, lambda tree: None)
        limits, child, support = PlacementLimits(hull_margin=0.5), "franka", "table"
    with pytest.raises(PlacementError) as placing:
        place(layout, 0, limits)
    with pytest.raises(PlacementError) as sampling:
        EpisodeSampler([layout], limits)
    assert str(placing.value) == str(sampling.value)
    message = str(placing.value)
    assert message.startswith(f"{tmp_path / 'layout.json'}: "), message
    assert f'cannot place "{child}"' in message
    assert f'the top of "{support}" is smaller than twice placement_limits.hull_margin' in message
    assert placing.value.node == child and placing.value.attempts == 0
