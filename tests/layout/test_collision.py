"""One-object concave collision meshes are decomposed into convex parts on load (CoACD, seeded,
cached outside the user's folder), or kept with one warning when the user opts out."""

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from embodied_envs.cli.main import main
from embodied_envs.layout import asset_geometry, parse_urdf
from embodied_envs.layout import collision as col

ROOT = Path(__file__).resolve().parents[2]
ZOO = ROOT / "tests" / "data" / "zoo"


def revolved_cup() -> trimesh.Trimesh:
    """A cup as a user's own export writes it: one watertight concave object (8 cm across,
    9 cm tall, 6 mm walls and bottom), Y-up as EmbodiedGen's meshes."""
    r, h, wall = 0.04, 0.09, 0.006
    profile = np.array([[0, 0], [r, 0], [r, h], [r - wall, h], [r - wall, wall], [0, wall]])
    cup = trimesh.creation.revolve(profile, sections=32)
    cup.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    return cup


def cup_asset(folder: Path) -> Path:
    """The zoo's handled cup folder with the revolved cup as its collision mesh; its URDF."""
    shutil.copytree(ZOO / "assets" / "handled_cup", folder / "handled_cup")
    revolved_cup().export(folder / "handled_cup" / "mesh" / "handled_cup_collision.obj")
    return folder / "handled_cup" / "handled_cup.urdf"


def snapshot(folder: Path) -> dict:
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def cup(tmp_path_factory):
    """The handled cup as one concave object, decomposed once into a module cache."""
    root = tmp_path_factory.mktemp("cup")
    cache = root / "cache"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(col.CACHE_ENV, str(cache))
        mp.delenv(col.OPT_OUT_ENV, raising=False)
        urdf = cup_asset(root / "assets")
        before = snapshot(root / "assets")
        spec = parse_urdf(urdf)
    return dict(urdf=urdf, spec=spec, cache=cache, before=before, root=root)


def test_a_concave_object_becomes_convex_parts_in_the_cache(cup):
    spec, urdf = cup["spec"], cup["urdf"]
    original = urdf.parent / "mesh" / "handled_cup_collision.obj"
    assert spec.collision.path.parent == cup["cache"] / "collision"
    assert snapshot(cup["root"] / "assets") == cup["before"], "nothing written beside the asset"
    parts = col.obj_objects(spec.collision.path)
    assert 4 <= len(parts) <= col.COACD_PARAMS["max_convex_hull"]
    reason, out = col.DECOMPOSED[original]
    assert out == spec.collision.path
    assert reason == "one concave object (its convex hull is 3.1x its volume)"
    # the parts follow the cup: their hulls hold far less than the one hull the simulator
    # would make (3.1x the cup's volume), and span the same box
    mesh = trimesh.load(original, force="mesh")
    hulls = [trimesh.Trimesh(p).convex_hull for p in parts]
    assert sum(h.volume for h in hulls) < 2.0 * mesh.volume
    lo = np.min([h.bounds[0] for h in hulls], 0)
    hi = np.max([h.bounds[1] for h in hulls], 0)
    assert np.allclose(lo, mesh.bounds[0], atol=4e-3) and np.allclose(hi, mesh.bounds[1], atol=4e-3)
    # placement reads the same parts: as tall as the cup (the mesh is Y-up, the link Z-up)
    geom = asset_geometry(spec)
    assert geom.max_z - geom.min_z == pytest.approx(np.ptp(mesh.bounds[:, 1]), abs=4e-3)  # Y-up


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
    layout["assets"] = {
        n: str((base / p).resolve()) for n, p in layout["assets"].items()
    } | {"handled_cup": str(cup["urdf"].parent)}
    path = tmp_path / "cup.json"
    path.write_text(json.dumps(layout))
    col._convex_collision.cache_clear()
    assert main(["layout", "validate", str(path)]) == 0
    out = capsys.readouterr().out
    line = [x for x in out.splitlines() if "decomposed" in x]
    assert len(line) == 1 and "handled_cup_collision.obj" in line[0], out
    assert "convex parts" in line[0] and str(cup["cache"]) in line[0]
