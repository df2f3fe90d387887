"""Collision meshes written as one object are made of convex parts on load without changing
their shape: one hull per convex piece (exact), CoACD only on a closed concave piece (no
manifold pre-processing, parts checked against the piece), cached by content and settings
outside the user's folder; degenerate meshes are refused before anything is decomposed."""

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull
from shapes import BOWL_FLOOR, bowl_wedges, round_table_pieces, table_pieces, write_asset

from embodied_envs.cli.main import main
from embodied_envs.layout import LayoutError, asset_geometry, hollow, parse_urdf
from embodied_envs.layout import collision as col

ROOT = Path(__file__).resolve().parents[2]
ZOO = ROOT / "tests" / "data" / "zoo"
EXACT = 1e-6  # m: the OBJ files' 6 decimals


def revolved_cup() -> trimesh.Trimesh:
    """A cup as a user's own export writes it: one watertight concave object (8 cm across,
    9 cm tall, 6 mm walls and bottom), Y-up as EmbodiedGen's meshes."""
    r, h, wall = 0.04, 0.09, 0.006
    profile = np.array([[0, 0], [r, 0], [r, h], [r - wall, h], [r - wall, wall], [0, wall]])
    cup = trimesh.creation.revolve(profile, sections=32)
    cup.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    return cup


CUP_FLOOR = 0.006  # m: the revolved cup's inside floor over its bottom


def cup_asset(folder: Path) -> Path:
    """The zoo's handled cup folder with the revolved cup as its collision and visual mesh (a
    collision mesh stands where its visual mesh does: layout/visual.py); its URDF."""
    shutil.copytree(ZOO / "assets" / "handled_cup", folder / "handled_cup")
    for name in ("handled_cup_collision.obj", "handled_cup.obj"):
        revolved_cup().export(folder / "handled_cup" / "mesh" / name)
    return folder / "handled_cup" / "handled_cup.urdf"


def snapshot(folder: Path) -> dict:
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def no_coacd(monkeypatch):
    import coacd

    def refuse(*a, **k):
        raise AssertionError("CoACD ran")

    monkeypatch.setattr(coacd, "run_coacd", refuse)


@pytest.fixture(scope="module")
def cup(tmp_path_factory):
    """The handled cup as one concave object, decomposed once into a module cache."""
    root = tmp_path_factory.mktemp("cup")
    cache = root / "cache"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(col.CACHE_ENV, str(cache))
        mp.delenv(col.OPT_OUT_ENV, raising=False)
        col._convex_collision.cache_clear()
        urdf = cup_asset(root / "assets")
        before = snapshot(root / "assets")
        spec = parse_urdf(urdf)
    return dict(urdf=urdf, spec=spec, cache=cache, before=before, root=root)


def hull_vertex_set(verts: np.ndarray) -> set:
    return {tuple(v) for v in np.round(verts[ConvexHull(verts).vertices], 6)}


@pytest.mark.parametrize(
    "shape, count",
    [(table_pieces, 5), (round_table_pieces, 3), (bowl_wedges, 17)],
    ids=["table", "round_table", "bowl_of_touching_parts"],
)
def test_pieces_written_as_one_object_become_their_own_hulls_exactly(
    shape, count, fresh, no_coacd, tmp_path
):
    urdf = write_asset(tmp_path / "assets", "thing", shape())
    original = urdf.parent / "mesh" / "thing_collision.obj"
    spec = parse_urdf(urdf)
    assert spec.collision.path.parent == fresh
    reason, out = col.DECOMPOSED[original]
    assert reason == f"one object of {count} disconnected pieces"
    written = col.obj_objects(original)[0]
    parts = col.obj_objects(out)
    assert len(parts) == count
    # every part is the hull of one piece, vertex for vertex: the bounds are the user's
    pieces = trimesh.load(original, force="mesh", process=False).split(only_watertight=False)
    assert sorted(map(sorted, map(hull_vertex_set, parts))) == sorted(
        map(sorted, (hull_vertex_set(np.asarray(p.vertices)) for p in pieces))
    )
    allv = np.concatenate(parts)
    np.testing.assert_allclose(allv.min(0), written.min(0), atol=EXACT)
    np.testing.assert_allclose(allv.max(0), written.max(0), atol=EXACT)


def test_a_bowl_of_touching_parts_keeps_its_floor(fresh, no_coacd, tmp_path):
    geom = asset_geometry(parse_urdf(write_asset(tmp_path / "assets", "bowl", bowl_wedges())))
    floor = col.solid_top(list(geom.parts), (0.0, 0.0)) - geom.min_z
    assert floor == pytest.approx(BOWL_FLOOR, abs=EXACT)


def test_a_concave_object_is_decomposed_within_its_shape(cup):
    spec, urdf = cup["spec"], cup["urdf"]
    original = urdf.parent / "mesh" / "handled_cup_collision.obj"
    assert spec.collision.path.parent == cup["cache"] / "collision"
    assert snapshot(cup["root"] / "assets") == cup["before"], "nothing written beside the asset"
    parts = col.obj_objects(spec.collision.path)
    assert 4 <= len(parts) <= col.COACD_PARAMS["max_convex_hull"]
    reason, out = col.DECOMPOSED[original]
    assert out == spec.collision.path
    assert reason == "one concave object (its convex hull is 3.1x its volume)"
    mesh = trimesh.load(original, force="mesh")
    # within the cup's bounding box, spanning all of it (to the file's 6 decimals)
    allv = np.concatenate(parts)
    np.testing.assert_allclose(allv.min(0), mesh.bounds[0], atol=col.BOUNDS_TOLERANCE)
    np.testing.assert_allclose(allv.max(0), mesh.bounds[1], atol=col.BOUNDS_TOLERANCE)
    assert (allv.min(0) >= mesh.bounds[0] - EXACT).all()
    assert (allv.max(0) <= mesh.bounds[1] + EXACT).all()
    # the parts hold the cup's volume within the stated ratio, far less than its one hull
    ratio = sum(ConvexHull(p).volume for p in parts) / mesh.volume
    assert col.VOLUME_RATIO[0] <= ratio <= col.VOLUME_RATIO[1]
    # the cup's floor stays where it is: a block dropped in rests on it
    geom = asset_geometry(spec)
    floor = col.solid_top(list(geom.parts), (0.0, 0.0)) - geom.min_z
    assert floor == pytest.approx(CUP_FLOOR, abs=col.BOUNDS_TOLERANCE)


def test_the_decomposition_is_cached_and_seeded(cup, monkeypatch, tmp_path):
    monkeypatch.setenv(col.CACHE_ENV, str(cup["cache"]))
    col._convex_collision.cache_clear()

    def no_coacd(*a, **k):
        raise AssertionError("decomposed again although cached")

    import coacd

    monkeypatch.setattr(coacd, "run_coacd", no_coacd)
    assert parse_urdf(cup["urdf"]).collision.path == cup["spec"].collision.path
    # a fresh cache: the same seed gives the same file, byte for byte
    monkeypatch.undo()
    monkeypatch.setenv(col.CACHE_ENV, str(tmp_path))
    col._convex_collision.cache_clear()
    again = parse_urdf(cup["urdf"]).collision.path
    assert again.parent == tmp_path / "collision"
    assert again.read_bytes() == cup["spec"].collision.path.read_bytes()
    col._convex_collision.cache_clear()


def test_the_settings_are_in_the_cache_key(fresh, no_coacd, monkeypatch, tmp_path):
    urdf = write_asset(tmp_path / "assets", "table", table_pieces())
    first = parse_urdf(urdf).collision.path
    col._convex_collision.cache_clear()
    monkeypatch.setattr(col, "METHOD", col.METHOD + 1)
    second = parse_urdf(urdf).collision.path
    col._convex_collision.cache_clear()
    monkeypatch.setitem(col.COACD_PARAMS, "threshold", 0.5)
    third = parse_urdf(urdf).collision.path
    assert len({first, second, third}) == 3 and all(p.parent == fresh for p in (second, third))


def grown_part(vertices, faces, **_):
    """A CoACD stand-in: the piece's hull grown 2 mm on every side (the manifold growth)."""
    hull = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces)).convex_hull
    centre = hull.bounds.mean(0)
    grow = 1 + 0.004 / np.ptp(hull.bounds, 0).min()
    return [[(hull.vertices - centre) * grow + centre, hull.faces]]


def one_hull(vertices, faces, **_):
    """A CoACD stand-in: the piece's hull, the blob the simulator makes."""
    hull = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces)).convex_hull
    return [[hull.vertices, hull.faces]]


@pytest.mark.parametrize(
    "coacd_result, words",
    [(grown_part, "mm past the piece's bounds"), (one_hull, "x its volume (outside")],
    ids=["grown", "filled"],
)
def test_a_decomposition_that_changes_the_shape_is_not_used(
    coacd_result, words, fresh, monkeypatch, tmp_path
):
    import coacd

    monkeypatch.setattr(coacd, "run_coacd", lambda m, **k: coacd_result(m.vertices, m.indices))
    urdf = cup_asset(tmp_path / "assets")
    original = urdf.parent / "mesh" / "handled_cup_collision.obj"
    with pytest.warns(UserWarning) as caught:
        assert parse_urdf(urdf).collision.path == original
    text = str(caught[0].message)
    assert text.startswith(f"{original}: one concave object") and words in text, text
    assert "kept as written" in text and "Fix:" in text
    # the refusal is cached too: not decomposed again
    col._convex_collision.cache_clear()
    monkeypatch.setattr(coacd, "run_coacd", lambda *a, **k: pytest.fail("decomposed again"))
    assert parse_urdf(urdf).collision.path == original
    assert original not in col.DECOMPOSED


def flattened(text: str, axis: int) -> str:
    """An OBJ's vertices all put at 0 along ``axis`` (a broken export flattened to a plane)."""
    out = []
    for line in text.splitlines():
        if line.startswith("v "):
            v = line.split()[1:4]
            v[axis] = "0.0"
            line = "v " + " ".join(v)
        out.append(line)
    return "\n".join(out) + "\n"


def collapsed(text: str) -> str:
    """An OBJ's vertices all at one point."""
    return "\n".join("v 0.01 0.02 0.03" if x.startswith("v ") else x for x in text.splitlines())


def tilted_flat(text: str) -> str:
    """An OBJ flattened onto a tilted plane (y = 0.7 x): thin along no coordinate axis."""
    out = []
    for line in text.splitlines():
        if line.startswith("v "):
            x, _, z = map(float, line.split()[1:4])
            line = f"v {x} {0.7 * x} {z}"
        out.append(line)
    return "\n".join(out) + "\n"


@pytest.mark.parametrize(
    "edit",
    [lambda t: flattened(t, 1), lambda t: flattened(t, 0), collapsed, tilted_flat],
    ids=["flat", "flat_sideways", "collapsed", "tilted_flat"],
)
@pytest.mark.parametrize("shape", ["table", "cup"])
def test_a_degenerate_mesh_is_refused_before_any_decomposition(
    edit, shape, fresh, no_coacd, tmp_path
):
    if shape == "table":
        urdf = write_asset(tmp_path / "assets", "thing", round_table_pieces())
    else:
        urdf = cup_asset(tmp_path / "assets")
    original = urdf.parent / "mesh" / f"{urdf.stem}_collision.obj"
    original.write_text(edit(original.read_text()))
    spec = parse_urdf(urdf)
    assert spec.collision.path == original and not fresh.exists()
    with pytest.raises(LayoutError) as e:
        asset_geometry(spec)
    assert str(e.value).startswith(f"{original}: the collision mesh is flat")
    assert "sink" in str(e.value) and "Fix:" in str(e.value)


def test_a_mesh_with_a_flat_piece_is_kept_as_written_with_a_warning(fresh, no_coacd, tmp_path):
    sheet = trimesh.Trimesh([[0, 0, 0.9], [0.2, 0, 0.9], [0, 0.2, 0.9]], [[0, 1, 2]])
    urdf = write_asset(tmp_path / "assets", "thing", [*table_pieces(), sheet])
    original = urdf.parent / "mesh" / "thing_collision.obj"
    with pytest.warns(UserWarning, match=r"its piece \d is flat, so it is kept as written"):
        assert parse_urdf(urdf).collision.path == original


def test_opting_out_keeps_the_mesh_and_warns_once(cup, monkeypatch):
    monkeypatch.setenv(col.OPT_OUT_ENV, "0")
    col._convex_collision.cache_clear()
    col._WARNED.clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        first = parse_urdf(cup["urdf"])
        col._convex_collision.cache_clear()
        parse_urdf(cup["urdf"])
    assert first.collision.path == cup["urdf"].parent / "mesh" / "handled_cup_collision.obj"
    texts = [str(w.message) for w in caught if col.OPT_OUT_ENV in str(w.message)]
    assert len(texts) == 1, texts
    assert str(first.collision.path) in texts[0] and "solid blob" in texts[0]
    assert "export one object per convex part" in texts[0]
    col._convex_collision.cache_clear()


@pytest.mark.parametrize("name", ["ball", "slab", "handled_cup", "shallow_bowl"])
def test_convex_objects_and_multi_object_exports_are_kept(name):
    mesh = ZOO / "assets" / name / "mesh" / f"{name}_collision.obj"
    assert col.concavity(mesh) is None
    assert parse_urdf(ZOO / "assets" / name / f"{name}.urdf").collision.path == mesh


def test_disconnected_pieces_in_one_object_are_found(tmp_path):
    a = trimesh.creation.box((0.02, 0.02, 0.02))
    b = trimesh.creation.box((0.02, 0.02, 0.02))
    b.apply_translation([0.06, 0, 0])
    path = tmp_path / "two.obj"
    trimesh.util.concatenate([a, b]).export(path)
    assert col.concavity(path) == "one object of 2 disconnected pieces"


def test_layout_validate_names_what_it_decomposed(cup, monkeypatch, tmp_path, capsys):
    monkeypatch.setenv(col.CACHE_ENV, str(cup["cache"]))
    layout = json.loads((ZOO / "layouts" / "handled_cup.json").read_text())
    base = ZOO / "layouts"
    layout["assets"] = {n: str((base / p).resolve()) for n, p in layout["assets"].items()} | {
        "handled_cup": str(cup["urdf"].parent)
    }
    path = tmp_path / "cup.json"
    path.write_text(json.dumps(layout))
    col._convex_collision.cache_clear()
    assert main(["layout", "validate", str(path)]) == 0
    out = capsys.readouterr().out
    line = [x for x in out.splitlines() if "decomposed" in x]
    assert len(line) == 1 and "handled_cup_collision.obj" in line[0], out
    assert "convex parts" in line[0] and str(cup["cache"]) in line[0]
    col._convex_collision.cache_clear()


@pytest.mark.parametrize("soup", [False, True], ids=["shared_vertices", "triangle_soup"])
def test_pieces_are_found_whatever_normals_and_vertex_sharing_the_file_has(soup, tmp_path):
    """Per-corner normals or unshared triangles (an STL-like export) do not split a piece."""
    table = trimesh.util.concatenate(table_pieces())
    if soup:
        table.unmerge_vertices()
    path = tmp_path / "table.obj"
    path.write_text(trimesh.exchange.obj.export_obj(table, include_normals=True))
    assert col.concavity(path) == "one object of 5 disconnected pieces"
    cup = revolved_cup()
    if soup:
        cup.unmerge_vertices()
    path.write_text(trimesh.exchange.obj.export_obj(cup, include_normals=True))
    assert col.concavity(path) == "one concave object (its convex hull is 3.1x its volume)"


def open_bowl() -> trimesh.Trimesh:
    """A bowl as one open surface, no thickness (a scan's or a careless export's)."""
    profile = np.array([[0.0, 0.0], [0.045, 0.0], [0.08, 0.055]])
    return trimesh.creation.revolve(profile, sections=32)


def test_an_open_concave_piece_is_named_among_pieces(tmp_path):
    """An open bowl among closed pieces: found concave by what its hull fills (its volume
    cannot be measured), the closed pieces convex."""
    parts = [*table_pieces(), open_bowl().apply_translation([0, 0, 0.9])]
    urdf = write_asset(tmp_path / "assets", "thing", parts)
    reason = col.concavity(urdf.parent / "mesh" / "thing_collision.obj")
    assert reason.startswith("one object of 6 disconnected pieces, 1 of them concave (not closed;")
    assert "hollow filled 55.0 mm over its floor" in reason, reason


def test_an_open_concave_piece_is_decomposed_as_a_shell_keeping_its_floor(fresh, tmp_path):
    """An open bowl (no thickness): made a closed shell, decomposed, its floor kept open."""
    spec = parse_urdf(write_asset(tmp_path / "assets", "bowl", [open_bowl()]))
    assert spec.collision.path.parent == fresh
    geom = asset_geometry(spec)
    floor = col.solid_top(list(geom.parts), (0.0, 0.0)) - geom.min_z
    assert floor == pytest.approx(0.0, abs=hollow.HOLLOW_TOLERANCE)
    assert geom.min_z == pytest.approx(-0.0275, abs=EXACT)  # the bowl's own bottom, no lower


def test_open_convex_pieces_are_not_warned_about(fresh, tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    sphere.update_faces(np.arange(len(sphere.faces)) != 0)  # one triangle missing: open
    path = tmp_path / "sphere.obj"
    path.write_text(trimesh.exchange.obj.export_obj(sphere))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert col.convex_collision(path) == path


def torus() -> trimesh.Trimesh:
    t = trimesh.creation.torus(0.05, 0.015)  # closed, concave: its hull is 1.6x its volume
    return t.apply_translation(-t.bounds.mean(0))


def one_object_asset(tmp_path, collision: trimesh.Trimesh) -> Path:
    urdf = write_asset(tmp_path, "ring", [torus()], [collision])
    return urdf.parent / "mesh" / "ring_collision.obj"


def test_obj_faces_with_negative_indices_count_back_from_their_line(tmp_path):
    """A triangle soup whose faces each name the three vertices written just before them
    (``f -3 -2 -1``), as the OBJ format reads relative indices (trimesh alone counts them from
    the file's end: every face the last three vertices, and the torus was refused)."""
    t = torus()
    path = one_object_asset(tmp_path, t)
    lines = ["o ring"]
    for face in t.faces:
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in t.vertices[face]]
        lines.append("f -3 -2 -1")
    path.write_text("\n".join(lines) + "\n")
    read = col.load_mesh(path)
    assert np.allclose(read.vertices[read.faces], t.vertices[t.faces], atol=1e-6)
    assert col.concavity(path) == "one concave object (its convex hull is 1.6x its volume)"
    assert col.absolute_indices(b"v 0 0 0\nv 1 0 0\nvt 0 0\nf -2/-1 -1/-1 1/1\n").endswith(
        b"f 1/1 2/1 1/1\n"
    )


def test_a_closed_mesh_written_inside_out_is_closed_and_concave(tmp_path):
    t = torus()
    path = one_object_asset(tmp_path, trimesh.Trimesh(t.vertices, t.faces[:, ::-1]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reason = col.concavity(path)
    assert reason == "one concave object (its convex hull is 1.6x its volume)"
    assert not [w for w in caught if "not closed" in str(w.message)]


def test_faces_written_twice_are_one_surface_not_a_piece_per_face(tmp_path):
    t = torus()
    twice = trimesh.Trimesh(t.vertices, np.concatenate([t.faces, t.faces[:, ::-1]]))
    path = one_object_asset(tmp_path, twice)
    assert col.concavity(path) == "one concave object (its convex hull is 1.6x its volume)"


def test_a_slow_decomposition_says_so_before_it_starts(fresh, monkeypatch, tmp_path, capsys):
    """One line, before CoACD runs, names the mesh and that it may take a minute (a 100,000
    face mesh takes most of one); a quick one does not say so."""
    path = cup_asset(tmp_path / "assets").parent / "mesh" / "handled_cup_collision.obj"
    faces = len(trimesh.load(path, force="mesh").faces)
    monkeypatch.setattr(col, "SLOW_FACES", faces - 1)
    import coacd

    def stop(*a, **k):
        raise KeyboardInterrupt  # the line came before the decomposition

    monkeypatch.setattr(coacd, "run_coacd", stop)
    with pytest.raises(KeyboardInterrupt):
        col.convex_collision(path)
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"{path}: one concave object")
    assert line.endswith(f"; it may take a minute ({faces:,} faces) ...")
    monkeypatch.setattr(col, "SLOW_FACES", faces)
    col._convex_collision.cache_clear()
    with pytest.raises(KeyboardInterrupt):
        col.convex_collision(path)
    assert "minute" not in capsys.readouterr().err
