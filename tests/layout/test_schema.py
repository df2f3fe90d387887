import json
import math

import pytest
from conftest import DATA, DEFAULT_LAYOUT, deep, snapshot, write_layout

from embodied_envs.layout import LayoutError, LayoutInfo, load_layout
from embodied_envs.layout.schema import RESERVED_NAMES, is_reserved


def test_round_trip_is_lossless_with_unknown_keys(tmp_path, layout_dict):
    data = deep(layout_dict)
    data["my_extra"] = {"nested": [1, 2, 3]}
    data["relation"]["my_relation_key"] = "kept"
    data["quality"] = {"can": "good"}
    data["assets"] = {k: str((DATA / "layouts" / v).resolve()) for k, v in data["assets"].items()}
    src = write_layout(tmp_path, data)
    info = load_layout(src)
    out = info.save(tmp_path / "out" / "again.json")
    again = json.loads(out.read_text())
    assert again["my_extra"] == {"nested": [1, 2, 3]}
    assert again["relation"]["my_relation_key"] == "kept"
    assert again["quality"] == {"can": "good"}
    assert again["position"] == data["position"]
    assert again["tree"] == data["tree"]
    reloaded = load_layout(out)
    assert reloaded.asset_dir("can") == info.asset_dir("can")


def test_assets_resolve_relative_to_layout_folder():
    info = load_layout(DEFAULT_LAYOUT)
    assert info.asset_dir("can") == (DATA / "assets" / "can").resolve()
    assert info.target_node == "can"
    assert info.urdf_path("can").name == "can.urdf"


def test_quaternion_within_tolerance_is_normalised(tmp_path, layout_dict):
    data = deep(layout_dict)
    data["assets"] = {k: str((DATA / "layouts" / v).resolve()) for k, v in data["assets"].items()}
    data["position"]["can"][3:] = [0, 0, 0, 1.0005]
    info = load_layout(write_layout(tmp_path, data))
    assert math.isclose(sum(v * v for v in info.position["can"][3:]), 1.0, abs_tol=1e-9)


def _abs_assets(data):
    data["assets"] = {k: str((DATA / "layouts" / v).resolve()) for k, v in data["assets"].items()}
    return data


CASES = [
    ("missing tree", lambda d: d.pop("tree"), ['"tree" is missing']),
    ("missing relation", lambda d: d.pop("relation"), ['"relation" is missing']),
    ("missing objs_mapping", lambda d: d.pop("objs_mapping"), ['"objs_mapping" is missing']),
    ("missing assets", lambda d: d.pop("assets"), ['"assets" is missing']),
    ("missing position", lambda d: d.pop("position"), ['"position" is missing']),
    (
        "6 numbers",
        lambda d: d["position"]["can"].pop(),
        ['position["can"] has 6 numbers, expected 7'],
    ),
    (
        "nan",
        lambda d: d["position"]["can"].__setitem__(0, float("nan")),
        ['position["can"]', "NaN"],
    ),
    (
        "zero quat",
        lambda d: d["position"]["can"].__setitem__(slice(3, 7), [0, 0, 0, 0]),
        ['position["can"] quaternion has norm 0'],
    ),
    (
        "robot pose",
        lambda d: d["position"].pop("franka"),
        ['position["franka"] (the robot) is missing'],
    ),
    ("asset missing", lambda d: d["assets"].pop("mug"), ['assets["mug"] is missing']),
    ("position missing", lambda d: d["position"].pop("mug"), ['position["mug"] is missing']),
    (
        "two contexts",
        lambda d: d["objs_mapping"].__setitem__("mug", "context"),
        ['2 "context" nodes'],
    ),
    (
        "bad category",
        lambda d: d["objs_mapping"].__setitem__("mug", "furniture"),
        ['objs_mapping["mug"] is "furniture"'],
    ),
    (
        "bad relation",
        lambda d: d["tree"]["table"].__setitem__(0, ["can", "ABOVE"]),
        ['relation of "can" is "ABOVE"'],
    ),
    (
        "not on table",
        lambda d: d["tree"]["table"].remove(["can", "ON"]),
        ['"can" does not rest on the context "table"'],
    ),
    (
        "no manipulated",
        lambda d: d["relation"].__setitem__("manipulated_objs", []),
        ['manipulated_objs"] is empty'],
    ),
]


@pytest.mark.parametrize("name,mutate,words", CASES, ids=[c[0] for c in CASES])
def test_validation_errors_name_file_node_and_field(tmp_path, layout_dict, name, mutate, words):
    data = _abs_assets(deep(layout_dict))
    mutate(data)
    path = write_layout(tmp_path, data)
    before = snapshot(tmp_path)
    with pytest.raises(LayoutError) as exc:
        load_layout(path)
    msg = str(exc.value)
    assert str(path) in msg
    for w in words:
        assert w in msg, msg
    assert snapshot(tmp_path) == before


def test_malformed_json(tmp_path):
    path = tmp_path / "layout.json"
    path.write_text('{"tree": {')
    with pytest.raises(LayoutError, match=r"not valid JSON .* line 1"):
        load_layout(path)


def test_missing_asset_folder(tmp_path, layout_dict):
    data = _abs_assets(deep(layout_dict))
    data["assets"]["mug"] = "no/such/folder"
    with pytest.raises(LayoutError, match=r'assets\["mug"\] folder no/such/folder does not exist'):
        load_layout(write_layout(tmp_path, data))


def test_urdf_named_after_node_with_underscores(tmp_path, layout_dict, scene_copy):
    layout = scene_copy / "layouts" / "default.json"
    data = json.loads(layout.read_text())
    # a node name with a space maps to a file stem with an underscore
    (scene_copy / "assets" / "can" / "can.urdf").rename(
        scene_copy / "assets" / "can" / "blue_can.urdf"
    )
    text = json.dumps(data).replace('"can"', '"blue can"')
    layout.write_text(text)
    info = load_layout(layout)
    assert info.urdf_path("blue can").name == "blue_can.urdf"


def test_from_dict_rejects_non_object():
    with pytest.raises(LayoutError, match="top level must be a JSON object"):
        LayoutInfo.from_dict([1, 2, 3])


def test_a_layout_file_over_its_size_bound_is_refused_unread(tmp_path, layout_dict):
    """A 2 MB unknown field would be copied into every generated variant: refused."""
    from embodied_envs.layout.loader import MAX_LAYOUT_BYTES

    layout_dict["notes"] = "x" * (2 * MAX_LAYOUT_BYTES)
    path = write_layout(tmp_path, layout_dict)
    with pytest.raises(LayoutError) as e:
        load_layout(path)
    assert str(path) in str(e.value) and "over the 1,048,576 a layout may hold" in str(e.value)


RESERVED = [*RESERVED_NAMES, "object1", "object12"]


def _renamed(data: dict, old: str, new: str) -> dict:
    """The layout with node ``old`` renamed ``new`` in every field."""
    return json.loads(json.dumps(data).replace(f'"{old}"', f'"{new}"'))


@pytest.mark.parametrize("name", RESERVED)
def test_a_node_named_like_what_the_env_registers_is_refused(tmp_path, layout_dict, name):
    """A node named "goal_site" (the env's goal marker) used to pass validation and fail inside
    ManiSkill with an AssertionError; every name the env registers is refused in one line."""
    path = write_layout(tmp_path, _renamed(_abs_assets(deep(layout_dict)), "mug", name))
    with pytest.raises(LayoutError) as e:
        load_layout(path)
    assert len(e.value.problems) == 1, e.value.problems
    msg = e.value.problems[0]
    assert msg.startswith(f'{path}: node name "{name}" is reserved'), msg
    assert f'Fix: rename the node (e.g. "{name}_1")' in msg and "\n" not in msg


def test_the_reserved_names_are_what_the_env_and_the_scene_name_their_own():
    assert {"ground", "goal_site", "target_obj", "context", "target"} <= set(RESERVED_NAMES)
    assert {"panda", "panda_wristcam", "base_camera", "render_camera"} <= set(RESERVED_NAMES)
    assert is_reserved("object3") and not is_reserved("object") and not is_reserved("objects1")


@pytest.mark.parametrize("name", ["ground_1", "Goal_site", "object", "object_1", "targets"])
def test_names_near_the_reserved_ones_are_accepted(layout_dict, name):
    info = LayoutInfo.from_dict(_renamed(deep(layout_dict), "mug", name))
    assert name in info.object_nodes()


def test_a_robot_named_by_its_uid_is_not_a_reserved_clash(layout_dict):
    info = LayoutInfo.from_dict(_renamed(deep(layout_dict), "franka", "panda"))
    assert info.robot == "panda"
