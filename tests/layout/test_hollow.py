"""The hollow rule (layout/hollow.py): probed from above in the object's frame, convex parts
that stand over a surface's floor by more than 2 mm fill a hollow, however the file is written
(an open surface, several objects, a recess too shallow for a volume ratio); such collision
meshes are decomposed on load, and what still fills a hollow is warned about in one line.
Shipped assets keep their collision files."""

import warnings

import numpy as np
import pytest
import trimesh
from conftest import DATA
from shapes import box, mug_objects, open_box, tray, write_asset

from embodied_envs.layout import collision as col
from embodied_envs.layout import hollow, parse_urdf
from embodied_envs.layout.visual import visual_hollow

MM = 1e-3


def hull_fill(mesh: trimesh.Trimesh) -> hollow.Hollow:
    return hollow.filled_hollow(mesh.triangles, [np.asarray(mesh.vertices)])


@pytest.mark.parametrize(
    "shape, depth",
    [(open_box, 0.08), (lambda: mug_objects()[0], 0.086), (tray, 0.01)],
    ids=["open_box", "mug_body", "shallow_tray"],
)
def test_a_hull_over_a_hollow_fills_it_by_its_depth(shape, depth):
    mesh = shape()
    assert tray().convex_hull.volume / tray().volume < col.CONCAVE_RATIO  # the ratio misses it
    found = hull_fill(mesh)
    assert found.filled and found.gap == pytest.approx(depth, abs=0.5 * MM)


@pytest.mark.parametrize(
    "mesh",
    [box([0.1, 0.06, 0.04], [0, 0, 0.02]), trimesh.creation.icosphere(2, 0.05), mug_objects()[1]],
    ids=["box", "ball", "handle"],
)
def test_a_convex_shape_has_no_hollow(mesh):
    assert not hull_fill(mesh).filled


def test_a_part_a_millimetre_past_the_foot_of_a_wall_is_no_hollow():
    """A tray's rim as 24 parts, each reaching 1 mm over the recess floor at the foot of the
    wall (as CoACD's parts do): no floor is covered."""
    t = tray()
    base = np.asarray(t.vertices)[np.asarray(t.vertices)[:, 2] < 0.031]
    rim = []
    for k in range(24):
        a = np.radians([15 * k, 15 * (k + 1)])
        rim.append(
            np.array(
                [
                    [r * np.cos(b), r * np.sin(b), z]
                    for b in a
                    for r in (0.089, 0.1)
                    for z in (0.03, 0.04)
                ]
            )  # fmt: skip
        )
    assert not hollow.filled_hollow(t.triangles, [base, *rim]).filled
    slab = np.array(box([0.1, 0.1, 0.01], [0, 0, 0.035]).vertices)  # over the floor: filled
    assert hollow.filled_hollow(t.triangles, [base, *rim, slab]).gap == pytest.approx(0.01, abs=MM)


def test_each_object_of_a_multi_object_file_is_probed(tmp_path):
    urdf = write_asset(tmp_path, "mug", mug_objects(), one_object=False)
    reason = col.concavity(urdf.parent / "mesh" / "mug_collision.obj")
    assert reason.startswith("2 objects, 1 of them concave (its convex hull is ")


def test_the_frame_is_the_urdfs(tmp_path):
    """Probed as the object rests: the same open box file lying on its side (turned by the
    URDF) has no hollow seen from above -- its opening faces sideways."""
    path = write_asset(tmp_path, "box", [open_box()]).parent / "mesh" / "box_collision.obj"
    assert "hollow filled 80.0 mm" in col.concavity(path)
    assert col.concavity(path, frame=tuple(np.eye(3).ravel())) is None  # Y up: on its side


def one_hull(m, **_):
    """A CoACD stand-in that fills everything in: the blob the simulator makes."""
    hull = trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.indices)).convex_hull
    return [[hull.vertices, hull.faces]]


def test_a_hollow_still_filled_is_warned_about_in_one_line(fresh, monkeypatch, tmp_path):
    import coacd

    monkeypatch.setattr(coacd, "run_coacd", one_hull)
    urdf = write_asset(tmp_path / "assets", "box", [open_box()])
    original = urdf.parent / "mesh" / "box_collision.obj"
    with pytest.warns(UserWarning) as caught:
        assert parse_urdf(urdf).collision.path == original
    [text] = [str(w.message) for w in caught if str(original) in str(w.message)]
    assert "\n" not in text and text.startswith(f"{original}: one concave object (not closed;")
    assert "still make a hollow filled 80.0 mm over its floor" in text
    assert "Fix: export one object per convex part" in text


def test_shipped_assets_keep_their_collision_files(fresh):
    """Every shipped collision object is convex: nothing is decomposed, none is re-written."""
    urdfs = sorted((DATA / "assets").glob("*/*.urdf"))
    assert len(urdfs) >= 13
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the bowl's own mismatch warning
        for urdf in urdfs:
            spec = parse_urdf(urdf)
            assert spec.collision.source is None, urdf
            assert spec.collision.path == urdf.parent / "mesh" / f"{urdf.stem}_collision.obj"
    assert not fresh.exists()


def test_the_shipped_hollows_are_open_in_their_collision():
    """The shipped mug's collision (a base, wall pieces, the handle), the bowls', the tray's and
    the storage box's leave their visual floors reachable: no filled hollow to warn about."""
    for name in ("mug", "bowl", "fruit_bowl", "tray", "storage_box"):
        assert not visual_hollow(parse_urdf(DATA / "assets" / name / f"{name}.urdf")).filled
