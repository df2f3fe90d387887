import pytest
import trimesh
from conftest import DATA

from embodied_envs.layout import LayoutError, asset_geometry, parse_urdf

URDF = """<?xml version="1.0"?>
<robot name="thing">
  <link name="thing">
    <visual><geometry><mesh filename="mesh/thing.obj" scale="1 1 1"/></geometry>
      <origin xyz="0 0 0" rpy="1.5708 0 0"/></visual>
    {collision}
    {inertial}
  </link>
</robot>
"""
COLLISION = """<collision><geometry><mesh filename="mesh/thing_collision.obj"/></geometry>
      <origin xyz="0 0 0.1" rpy="1.5708 0 0"/>{gazebo}</collision>"""


def make_asset(tmp_path, collision=COLLISION, gazebo="", inertial="", mesh_text=None):
    (tmp_path / "mesh").mkdir(exist_ok=True)
    cube = (DATA / "assets" / "cracker_box" / "mesh" / "cracker_box_collision.obj").read_text()
    (tmp_path / "mesh" / "thing.obj").write_text(cube)
    (tmp_path / "mesh" / "thing_collision.obj").write_text(
        mesh_text if mesh_text is not None else cube
    )
    path = tmp_path / "thing.urdf"
    path.write_text(URDF.format(collision=collision.format(gazebo=gazebo), inertial=inertial))
    return path


def test_parse_shipped_urdf_friction_clipped_and_mass():
    spec = parse_urdf(DATA / "assets" / "can" / "can.urdf")
    assert spec.static_friction == 0.7 and spec.dynamic_friction == 0.6
    assert spec.mass == pytest.approx(0.15)
    assert spec.visual.rpy == pytest.approx((1.5708, 0, 0))
    assert spec.collision.path.name == "can_collision.obj"


def test_friction_clipping_and_defaults(tmp_path):
    s = parse_urdf(make_asset(tmp_path, gazebo="<gazebo><mu1>2.0</mu1><mu2>0.01</mu2></gazebo>"))
    assert (s.static_friction, s.dynamic_friction) == (0.7, 0.1)
    s = parse_urdf(make_asset(tmp_path))
    assert (s.static_friction, s.dynamic_friction) == (0.5, 0.4)
    assert s.mass is None


def test_origin_applied_y_up_to_z_up(tmp_path):
    geom = asset_geometry(parse_urdf(make_asset(tmp_path)))
    # the cracker box is 0.05 x 0.09 x 0.13 (Z-up design); stored Y-up; origin z + 0.1
    ext = geom.vertices.max(0) - geom.vertices.min(0)
    assert ext == pytest.approx([0.05, 0.09, 0.13], abs=1e-4)
    assert (geom.vertices.max(0) + geom.vertices.min(0))[2] / 2 == pytest.approx(0.1, abs=1e-4)
    assert len(geom.parts) == 2 and geom.volume == pytest.approx(0.05 * 0.09 * 0.13, rel=1e-3)


def test_missing_collision_is_an_error(tmp_path):
    with pytest.raises(LayoutError, match="link has no <collision>"):
        parse_urdf(make_asset(tmp_path, collision=""))


def test_not_a_mesh_and_empty_mesh(tmp_path):
    spec = parse_urdf(make_asset(tmp_path, mesh_text="this is not a mesh\n"))
    with pytest.raises(LayoutError, match="thing_collision.obj"):
        asset_geometry(spec)
    spec = parse_urdf(
        make_asset(tmp_path / "x" if (tmp_path / "x").mkdir() is None else tmp_path, mesh_text="")
    )
    with pytest.raises(LayoutError, match="empty|not a readable mesh"):
        asset_geometry(spec)


def test_invalid_xml(tmp_path):
    p = tmp_path / "bad.urdf"
    p.write_text("<robot><link>")
    with pytest.raises(LayoutError, match="not valid XML"):
        parse_urdf(p)


def test_heavy_collision_mesh_is_warned_about_once_with_its_cost(tmp_path):
    import shutil
    import warnings

    import trimesh

    from embodied_envs.layout import asset_geometry
    from embodied_envs.layout.assets import HEAVY_COLLISION_FACES

    asset = tmp_path / "mug"
    shutil.copytree(DATA / "assets" / "mug", asset)
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=0.04)  # 81,920 faces
    assert len(sphere.faces) > HEAVY_COLLISION_FACES
    sphere.export(asset / "mesh" / "mug_collision.obj")
    spec = parse_urdf(asset / "mug.urdf")
    with pytest.warns(UserWarning, match=r"81,920 faces.*slow.*Fix: simplify"):
        asset_geometry(spec)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        asset_geometry(spec)  # cached: no second warning


def test_png_bytes_named_obj_are_named_as_what_they_are(tmp_path):
    png = b"\x89PNG\r\n\x1a\n" + bytes(64)
    spec = parse_urdf(make_asset(tmp_path, mesh_text=""))
    spec.collision.path.write_bytes(png)
    with pytest.raises(LayoutError, match="not a mesh file: its bytes are a PNG image") as e:
        asset_geometry(spec)
    assert "empty" not in str(e.value)


def test_a_mesh_in_millimetres_is_refused_saying_so(tmp_path):
    box = trimesh.creation.box((66.0, 100.0, 66.0))  # a can's box in millimetres, stored Y-up
    lines = [f"v {x} {y} {z}" for x, y, z in box.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in box.faces]
    spec = parse_urdf(make_asset(tmp_path, mesh_text="\n".join(lines) + "\n"))
    with pytest.raises(LayoutError, match=r"66 x 66 x 100 m .*millimetres.*0\.001") as e:
        asset_geometry(spec)
    assert str(spec.collision.path) in str(e.value)


def test_a_heavy_decomposition_is_warned_about_naming_the_users_mesh(monkeypatch, tmp_path):
    """Three fine spheres written as one object become three hulls of 20,480 faces each, made
    on load into the cache folder: the warning names the user's file, not the cache file."""
    import numpy as np
    from shapes import write_asset

    from embodied_envs.layout import collision as col

    monkeypatch.setenv(col.CACHE_ENV, str(tmp_path / "cache"))
    col._convex_collision.cache_clear()
    spheres = [
        trimesh.creation.icosphere(subdivisions=5, radius=0.02).apply_translation([x, 0, 0.02])
        for x in (-0.05, 0, 0.05)
    ]
    spec = parse_urdf(write_asset(tmp_path / "assets", "beads", spheres))
    original = spec.urdf_path.parent / "mesh" / "beads_collision.obj"
    assert spec.collision.source == original and spec.collision.named == original
    assert spec.collision.path.is_relative_to(tmp_path / "cache")
    with pytest.warns(UserWarning) as caught:
        asset_geometry(spec)
    [text] = [str(w.message) for w in caught if "faces" in str(w.message)]
    assert text.startswith(f"{original}: its convex parts, made on load ({spec.collision.path})")
    assert "61,440 faces" in text and "Fix: simplify it" in text
    assert len(asset_geometry(spec).parts) == 3 and np.isfinite(asset_geometry(spec).volume)
    col._convex_collision.cache_clear()
