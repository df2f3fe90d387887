"""EmbodiedGen's grasp annotations (issue 36 item 3): ``affordance_annot.json`` found where
EmbodiedGen writes it, read in GraspGen's gripper frame, checked like a synthesised grasp, ranked
first by confidence; a malformed file refused naming the file and the field."""

import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from embodied_envs.layout import parse_urdf
from embodied_envs.layout.affordance import (
    GRASPGEN_TCP_DEPTH,
    AffordanceError,
    annotation_path,
    read_annotation,
)
from embodied_envs.paths import data_root
from embodied_envs.solvers.grasps import GraspConfig, asset_grasps, posed_grasps
from embodied_envs.solvers.gripper import GripperModel


def graspgen_entry(centre, closing, approach, confidence):
    """A grasp in EmbodiedGen's file form, written independently of the module: the gripper
    root's pose (x closes, z approaches, the TCP GRASPGEN_TCP_DEPTH along z)."""
    x = closing / np.linalg.norm(closing)
    z = approach / np.linalg.norm(approach)
    rot = np.stack([x, np.cross(z, x), z], 1)
    qx, qy, qz, qw = Rotation.from_matrix(rot).as_quat()
    return {
        "confidence": confidence,
        "position": (centre - GRASPGEN_TCP_DEPTH * z).tolist(),
        "orientation": {"w": qw, "xyz": [qx, qy, qz]},
    }


SHALLOW = 0.002  # m: a TCP this far outside the material (any sampled grasp's, on any machine)


def pulled_out(grasps, k: int) -> np.ndarray:
    """Grasp ``k``'s TCP moved back along its approach until it lies outside every convex part
    of the asset (``grasps.planes``) by SHALLOW."""
    point, back = grasps.centre[k].copy(), -grasps.approach[k]
    while True:
        exits = []
        for p in grasps.planes:
            n, d = p[:, :3], p[:, 3]
            if (n @ point + d < 0).all():  # inside this part: where the line leaves it
                out = n @ back > 0
                exits.append(np.min(-(n[out] @ point + d[out]) / (n[out] @ back)))
        if not exits:
            return point + SHALLOW * back
        point = point + (max(exits) + 1e-6) * back


@pytest.fixture()
def mug(tmp_path):
    folder = tmp_path / "mug"
    shutil.copytree(data_root() / "assets" / "mug", folder)
    return folder


def write_annotation(folder, parts, where="affordance/affordance_annot.json"):
    path = folder / where
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps({"affordances": parts}))
    return path


def test_annotated_grasps_rank_first_by_confidence_and_invalid_ones_are_dropped(mug):
    plain = asset_grasps(parse_urdf(mug / "mug.urdf"))
    assert annotation_path(mug / "mug.urdf") is None and plain.annotated is None
    # two of the synthesis' own worst grasps (valid by construction), one grasping air 20 cm
    # away, one on a part marked not graspable
    worst, second = len(plain) - 1, len(plain) - 2
    entry = [graspgen_entry(plain.centre[i], plain.closing[i], plain.approach[i], c)
             for i, c in ((worst, 0.7), (second, 0.95))]  # fmt: skip
    air = graspgen_entry(plain.centre[0] + [0.2, 0, 0], plain.closing[0], plain.approach[0], 0.99)
    # the best grasp pulled back along its approach until the TCP (where the fingers close) is
    # SHALLOW outside the material: dropped, whichever grasp a machine's sample ranks best
    shallow = graspgen_entry(pulled_out(plain, 0), plain.closing[0], plain.approach[0], 0.98)
    write_annotation(mug, [
        {"part_name": "handle", "graspable": True, "id": 0,
         "grasp_group": {"grasp_3": entry[0], "grasp_9": entry[1], "grasp_11": air,
                         "grasp_12": shallow}},
        {"part_name": "rim", "graspable": False, "id": 1,
         "grasp_group": {"grasp_1": graspgen_entry(plain.centre[0], plain.closing[0],
                                                   plain.approach[0], 1.0)}},
    ])  # fmt: skip
    a = read_annotation(mug / "affordance" / "affordance_annot.json")
    assert len(a) == 4 and a.part == ("handle",) * 4
    np.testing.assert_allclose(a.confidence, [0.99, 0.98, 0.95, 0.7])
    np.testing.assert_allclose(a.centre[2], plain.centre[second], atol=1e-9)
    np.testing.assert_allclose(a.closing[3], plain.closing[worst], atol=1e-9)
    np.testing.assert_allclose(a.approach[3], plain.approach[worst], atol=1e-9)

    merged = asset_grasps(parse_urdf(mug / "mug.urdf"))
    assert len(merged) == len(plain) + 2, "the grasp of air and the shallow one are dropped"
    assert merged.annotated.tolist() == [True, True] + [False] * len(plain)
    # by confidence (both clear the mug alike or the roomier first): the 0.95 one leads
    lead = 0 if merged.score[0] <= merged.score[1] else 1
    assert merged.annotated[:2].all() and (merged.score[:2] < merged.score[2:].min()).all()
    firsts = {tuple(np.round(merged.centre[k], 9)) for k in (0, 1)}
    assert firsts == {tuple(np.round(plain.centre[i], 9)) for i in (worst, second)}
    if merged.score[0] // 1 == merged.score[1] // 1:  # same roominess: confidence decides
        np.testing.assert_allclose(merged.centre[lead], plain.centre[second], atol=1e-9)
    # the synthesised grasps follow in their own order, unchanged
    np.testing.assert_array_equal(merged.centre[2:], plain.centre)
    # the approach opening is the material between the fingers, pre-shaped, within the opening
    cfg, gripper = GraspConfig(), GripperModel()
    for k in (0, 1):
        i = worst if np.allclose(merged.centre[k], plain.centre[worst]) else second
        assert merged.width[k] <= gripper.opening - cfg.width_margin
        assert merged.opening[k] == pytest.approx(
            min(gripper.opening, merged.width[k] + 2 * cfg.preshape))
        assert merged.width[k] == pytest.approx(plain.width[i], abs=0.01)


def test_posed_expert_candidates_start_with_the_annotated_grasp(mug):
    plain = asset_grasps(parse_urdf(mug / "mug.urdf"))
    pose = np.eye(4)
    pose[:3, 3] = [0.1, 0.0, 0.8]
    # among the grasps the gripper can take here, the synthesis' last one, annotated
    taken = posed_grasps(plain, pose, support_z=0.78, limit=50)
    last = taken[-1]
    local = (last[0] - pose[:3, 3], last[1], last[2])
    write_annotation(mug, [{"part_name": "body", "graspable": True, "id": 0,
                            "grasp_group": {"grasp_0": graspgen_entry(*local, 0.9)}}])
    merged = asset_grasps(parse_urdf(mug / "mug.urdf"))
    first = posed_grasps(merged, pose, support_z=0.78, limit=8)[0]
    np.testing.assert_allclose(first[0], last[0], atol=1e-9)
    np.testing.assert_allclose(first[2], last[2], atol=1e-9)


def test_the_file_is_found_where_embodiedgen_puts_it(mug):
    urdf = mug / "mug.urdf"
    beside = write_annotation(mug, [], where="affordance_annot.json")
    assert annotation_path(urdf) == beside
    default = write_annotation(mug, [])
    assert annotation_path(urdf) == default, "affordance-cli's default folder first"
    named = write_annotation(mug, [], where="out/annot.json")
    text = urdf.read_text()
    tag = "<custom_data><affordance><affordance_annot>out/annot.json</affordance_annot>"
    urdf.write_text(text.replace("</robot>", tag + "</affordance></custom_data></robot>"))
    assert annotation_path(urdf) == named.resolve(), "the URDF's custom_data wins"
    named.unlink()
    with pytest.raises(AffordanceError) as e:
        annotation_path(urdf)
    assert str(urdf) in str(e.value) and "out/annot.json" in str(e.value)
    assert "Fix: correct the path" in str(e.value)


@pytest.mark.parametrize(
    "payload, words",
    [
        ("{not json", ["the file is not readable JSON"]),
        ({"parts": []}, ["'affordances' is missing or not a list"]),
        ({"affordances": [3]}, ["affordances[0] is not an object"]),
        ({"affordances": [{"grasp_group": {"g": {"confidence": 1, "position": [0, 0, 0]}}}]},
         ["affordances[0].grasp_group.g lacks a number", "orientation"]),
        ({"affordances": [{"grasp_group": {"g": {"confidence": 1, "position": [0, 0],
                                                 "orientation": {"w": 1, "xyz": [0, 0, 0]}}}}]},
         ["affordances[0].grasp_group.g needs a finite confidence, 3 position"]),
        ({"affordances": [{"grasp_group": {"g": {"confidence": 1, "position": [0, 0, 0],
                                                 "orientation": {"w": 2, "xyz": [0, 0, 0]}}}}]},
         ["affordances[0].grasp_group.g has an orientation of norm 2.000"]),
    ],
)  # fmt: skip
def test_a_malformed_file_names_the_file_and_the_field(mug, payload, words):
    path = mug / "affordance_annot.json"
    path.write_text(payload if isinstance(payload, str) else json.dumps(payload))
    before = path.read_bytes()
    with pytest.raises(AffordanceError) as e:
        read_annotation(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and "Fix: re-run EmbodiedGen's affordance-cli" in msg
    for w in words:
        assert w in msg
    assert path.read_bytes() == before


def test_the_expert_tries_the_annotated_grasp_first(scene_copy):
    """On place_tray the mug's first candidate is otherwise a synthesised grasp (the top-down
    footprint grasp across its bounding box's centre fails the checks on its hollow body); with
    one annotated grasp the gripper can take, the expert tries that one first."""
    import gymnasium as gym

    from embodied_envs.layout.pose import LayoutPose
    from embodied_envs.solvers import PickPlaceSolver

    layout = scene_copy / "layouts" / "place_tray.json"
    mug = scene_copy / "assets" / "mug"
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout), control_mode="pd_joint_pos")
    try:
        env.reset(seed=1)
        solver = PickPlaceSolver(env, seed=1)
        before = solver.grasp_poses()[0]
        u = env.unwrapped
        pose = LayoutPose.from_raw(u.env_actors["env0"]["mug"].pose.raw_pose[0].cpu().numpy())
        plain = asset_grasps(parse_urdf(mug / "mug.urdf"), solver.grasp_config)
        taken = posed_grasps(plain, pose.matrix(), float(u.layout_scene.top_z[0]),
                             solver.clouds[0], solver.grasp_config, limit=50)  # fmt: skip
        centre, closing, approach, _ = taken[-1]  # one the gripper can take, ranked last
        world_to_object = np.linalg.inv(pose.matrix())
        rot, t = world_to_object[:3, :3], world_to_object[:3, 3]
        write_annotation(mug, [{"part_name": "handle", "graspable": True, "id": 0,
                                "grasp_group": {"grasp_0": graspgen_entry(
                                    rot @ centre + t, rot @ closing, rot @ approach, 0.9)}}])
        after = solver.grasp_poses()[0]
        want = u.agent.build_grasp_pose(approach, closing, centre)
        # the same grasp with the jaws swapped: the expert folds the closing line toward the
        # hand's (SolverConfig.consistent), a parallel jaw's two equivalent orientations
        swapped = u.agent.build_grasp_pose(approach, -closing, centre)
    finally:
        env.close()
    assert not np.allclose(before[0][0].p, want.p, atol=1e-6)
    np.testing.assert_allclose(after[0][0].p, want.p, atol=1e-6)
    turn = max(abs(float(after[0][0].q @ q)) for q in (want.q, swapped.q))
    np.testing.assert_allclose(turn, 1.0, atol=1e-6)
    # the grasp that led before now follows the annotated one
    assert any(np.allclose(a[0].p, before[0][0].p, atol=1e-6) for a in after[1:])


def test_layout_validate_reports_annotations_and_refuses_a_broken_file(scene_copy, capsys):
    from embodied_envs.cli.main import main

    layout = scene_copy / "layouts" / "place_tray.json"
    mug = scene_copy / "assets" / "mug"
    plain = asset_grasps(parse_urdf(mug / "mug.urdf"))
    entries = {f"grasp_{i}": graspgen_entry(plain.centre[i], plain.closing[i], plain.approach[i],
                                            0.9) for i in range(3)}  # fmt: skip
    path = write_annotation(mug, [
        {"part_name": "handle", "graspable": True, "grasp_group": entries},
        {"part_name": "body", "graspable": True, "grasp_group": {}},
    ])
    assert main(["layout", "validate", "--no-placement", str(layout)]) == 0
    out = capsys.readouterr().out
    assert f"mug: 3 annotated grasps on 1 graspable part ({path})" in out
    path.write_text('{"affordances": 7}')
    assert main(["layout", "validate", "--no-placement", str(layout)]) == 1
    out = capsys.readouterr().out
    assert f"FAIL {layout}" in out and f"mug: {path}: 'affordances' is missing or not a list" in out
