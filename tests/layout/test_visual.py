"""The visual mesh's checks (layout/visual.py): its collision mesh compared with it on every face
of the two boxes and by volume; a collision mesh far off refused in one line naming the URDF,
one a few millimetres off warned about once."""

import re
import warnings

import pytest
from conftest import DATA
from shapes import box, write_asset

from embodied_envs.layout import LayoutError, parse_urdf
from embodied_envs.layout import visual as vis
from embodied_envs.layout.visual import check_visual_mesh

ROOT = DATA.parent.parent
ZOOS = ("zoo", "small_zoo", "small_zoo_hidden")  # tests/data/upright uses the shipped assets
# shipped assets whose collision mesh is not their visual mesh's shape, and how (the expected
# warnings): the bowl's collision is a 10-sided rim inside its 40-sided visual rim (3.7 mm
# short on -y and +y); the mug's follows its hollow visual mesh (not warned about)
SHIPPED_APART = {
    "bowl": r"faces stand -y -3\.7 mm, \+y -3\.7 mm off its visual box's",
}
CAN = [box([0.066, 0.066, 0.12], [0, 0, 0.06])]  # a can-sized box, its bottom at z = 0


def asset(tmp_path, collision=None, stem="thing", visual=CAN):
    return parse_urdf(write_asset(tmp_path, stem, visual, collision, one_object=False))


def moved(meshes, offset):
    return [m.copy().apply_translation(offset) for m in meshes]


def refusal(spec) -> str:
    with pytest.raises(LayoutError) as e:
        check_visual_mesh(spec)
    text = str(e.value)
    assert "\n" not in text and text.startswith(f"{spec.urdf_path}: ")
    return text


def test_a_collision_mesh_5_cm_sideways_is_refused_with_both_boxes_and_the_fix(tmp_path):
    spec = asset(tmp_path, moved(CAN, [0.05, 0, 0]))
    text = refusal(spec)
    assert "apart from its visual mesh by up to 50.0 mm, over 5.0 mm" in text
    assert "-x -50.0 mm, +x +50.0 mm" in text  # the faces apart, and no other
    assert "collision box [0.0170..0.0830, " in text and "visual box [-0.0330..0.0330, " in text
    assert text.endswith(
        "Fix: Export the collision mesh from the visual mesh's shape, in the same frame."
    )


def test_a_collision_mesh_5_cm_lower_is_refused(tmp_path):
    text = refusal(asset(tmp_path, moved(CAN, [0, 0, -0.05])))
    assert "-z +50.0 mm, +z -50.0 mm" in text and "float" in text


def test_a_collision_mesh_turned_is_refused(tmp_path):
    """A collision mesh lying where the visual one stands (its URDF origin forgot the Y-up
    turn, or the mesh was exported Z-up): its box's sides swapped."""
    spec = asset(tmp_path)
    text = spec.urdf_path.read_text()
    turned = 'rpy="1.5708 0 0"/>\n      <gazebo'
    assert turned in text  # the collision's origin
    spec.urdf_path.write_text(text.replace(turned, 'rpy="0 0 0"/>\n      <gazebo'))
    text = refusal(parse_urdf(spec.urdf_path))
    assert "Fix: give <visual> and <collision> the same <origin> and scale in the URDF" in text
    assert (
        "rpy [1.5708, 0.0, 0.0] scale [1.0, 1.0, 1.0] and xyz [0.0, 0.0, 0.0] rpy [0.0, 0.0, 0.0]"
        in text
    )


def test_a_visual_mesh_in_millimetres_is_refused_with_its_scale(tmp_path):
    spec = asset(tmp_path, CAN, visual=[box([66.0, 66.0, 120.0], [0, 0, 60.0])])
    text = refusal(spec)
    assert "reads as written in millimetres" in text
    assert 'scale="0.001 0.001 0.001"' in text


def test_a_collision_mesh_3_mm_sideways_is_warned_about_once(tmp_path):
    spec = asset(tmp_path, moved(CAN, [0, 0.003, 0]))
    with pytest.warns(UserWarning) as caught:
        check_visual_mesh(spec)
    [text] = [str(w.message) for w in caught]
    assert text.startswith(f"{spec.urdf_path}: its collision box's faces stand -y -3.0 mm, +y")
    assert "visual box [" in text and "Fix:" in text and "\n" not in text
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_visual_mesh(spec)  # once per URDF


def test_a_large_object_is_refused_beyond_its_share_only(tmp_path):
    """A 1.1 m table's collision 1 cm high is warned about (2 % of its size: 22 mm), 3 cm
    high refused."""
    top = [box([1.1, 0.7, 0.04], [0, 0, 0.74]), box([0.05, 0.05, 0.72], [0, 0, 0.36])]
    spec = asset(tmp_path, moved(top, [0, 0, 0.01]), "table", top)
    with pytest.warns(UserWarning, match=r"-z -10\.0 mm, \+z \+10\.0 mm"):
        check_visual_mesh(spec)
    text = refusal(asset(tmp_path, moved(top, [0, 0, 0.03]), "table2", top))
    assert "by up to 30.0 mm, over 22.0 mm" in text


def test_a_filled_hollow_of_the_same_box_is_warned_about_by_volume(tmp_path):
    """An open-topped box (a floor and four walls, 4 mm thick, each closed) over a solid block
    collision: every face agrees, the volume does not."""
    o, t = 0.08, 0.004  # outer size, wall thickness
    cup = [
        box([o, o, t], [0, 0, t / 2]),
        *(box([o, t, o - t], [0, s * (o - t) / 2, (o + t) / 2]) for s in (-1, 1)),
        *(box([t, o - 2 * t, o - t], [s * (o - t) / 2, 0, (o + t) / 2]) for s in (-1, 1)),
    ]
    spec = asset(tmp_path, [box([o] * 3, [0, 0, o / 2])], visual=cup)
    with pytest.warns(UserWarning, match=r"a hollow filled in") as caught:
        check_visual_mesh(spec)
    text = str(caught[0].message)
    assert "faces stand" not in text  # the boxes agree
    assert "collision volume is 512.0 cm^3 against its visual mesh's 118.0 cm^3" in text


def test_shipped_and_zoo_assets_agree_with_their_visual_meshes(monkeypatch):
    """No shipped or zoo asset is refused; only the true mismatches of ``SHIPPED_APART`` warn."""
    monkeypatch.setattr(vis, "_WARNED_MISMATCH", set())  # warned before in this process
    urdfs = sorted((DATA / "assets").glob("*/*.urdf"))
    for zoo in ZOOS:
        urdfs += sorted((ROOT / "tests" / "data" / zoo / "assets").glob("*/*.urdf"))
    assert len(urdfs) == 45
    for urdf in urdfs:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_visual_mesh(parse_urdf(urdf))
        texts = [str(w.message) for w in caught if "collision mesh, so on camera" in str(w.message)]
        expected = SHIPPED_APART.get(urdf.stem) if urdf.is_relative_to(DATA) else None
        if expected is None:
            assert texts == [], urdf
        else:
            assert len(texts) == 1 and re.search(expected, texts[0]), texts
