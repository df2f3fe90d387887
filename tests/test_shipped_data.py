"""Every generator of shipped data in tools/make/ writes, into a temporary folder, what is
shipped: the assets and the room's splat (make_assets.py, mesh_to_splat.py), the layouts
(make_layouts.py), the grasp zoo (make_grasp_zoo.py), the upright-mover layouts
(make_upright.py), the small-arm zoo and its held-out set (make_small_zoo.py), the splat rooms
(make_rooms.py) and the bad-input corpus (make_bad_inputs.py). Files are compared as data
(``tests/data_compare.py``: meshes by geometry, PLY and JSON by value within tolerances that
follow from the written precision), so the check holds on any processor and library release,
and still fails on a real change (tested below). A failure names the files that differ, why,
and the script that writes them."""

import importlib.util
import sys

import numpy as np
import pytest
import trimesh
from conftest import DATA, ROOT, snapshot
from data_compare import OBJ_STEP, differ, parse_obj, parse_ply

TOOLS = ROOT / "tools" / "make"
SHIPPED = {
    "assets": DATA / "assets",
    "layouts": DATA / "layouts",
    "zoo": ROOT / "tests" / "data" / "zoo",
    "upright": ROOT / "tests" / "data" / "upright",
    "small_zoo": ROOT / "tests" / "data" / "small_zoo",
    "small_zoo_hidden": ROOT / "tests" / "data" / "small_zoo_hidden",
    "bad_inputs": ROOT / "tests" / "data" / "bad_inputs",
    "rooms": DATA / "rooms",
}


@pytest.fixture(scope="module")
def tool():
    """A script of tools/make/ as a module, by its file name (tools/make/ on the path, as when
    the scripts run: they import each other); every module loaded is unloaded afterwards."""
    before = set(sys.modules)
    sys.path.insert(0, str(TOOLS))
    try:
        yield _load
    finally:
        sys.path.remove(str(TOOLS))
        for name in set(sys.modules) - before:
            if (getattr(sys.modules[name], "__file__", None) or "").startswith(str(TOOLS)):
                del sys.modules[name]


def _load(name: str):
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = sys.modules[name] = importlib.util.module_from_spec(spec)  # dataclasses need it
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module", autouse=True)
def shipped_untouched():
    """No generator writes into the shipped folders while it is tested."""
    before = {k: snapshot(v) for k, v in SHIPPED.items()}
    yield
    assert {k: snapshot(v) for k, v in SHIPPED.items()} == before


def files(folder) -> list[str]:
    return [str(p.relative_to(folder)) for p in sorted(folder.rglob("*")) if p.is_file()]


def assert_same_files(written, shipped, script: str) -> None:
    got, want = files(written), files(shipped)
    assert got == want, (
        f"{script} writes {sorted(set(got) - set(want))} and not {sorted(set(want) - set(got))}"
    )
    why = {k: w for k in want if (w := differ(written / k, shipped / k))}
    assert not why, f"{script} does not reproduce {sorted(why)} of {shipped}: {why}"
    assert want, f"{shipped} holds no file"


def test_make_assets_and_mesh_to_splat_reproduce_the_shipped_assets(tmp_path, tool):
    out = tmp_path / "assets"
    tool("make_assets").main(["--out", str(out)])
    background = out / "background"
    tool("mesh_to_splat").main(
        [str(background / "mesh_model.ply"), "--out", str(background / "gs_model.ply")]
    )
    script = "tools/make/make_assets.py + tools/make/mesh_to_splat.py"
    assert_same_files(out, SHIPPED["assets"], script)


@pytest.mark.parametrize(
    "script, shipped, args",
    [("make_layouts", "layouts", []), ("make_grasp_zoo", "zoo", []),
     ("make_upright", "upright", []), ("make_small_zoo", "small_zoo", []),
     ("make_small_zoo", "small_zoo_hidden", ["--hidden"]), ("make_rooms", "rooms", [])],
)  # fmt: skip
def test_a_generator_reproduces_what_it_ships(tmp_path, tool, script, shipped, args):
    """The shipped layouts, the grasp zoo, the upright-mover layouts and the small-arm zoo
    (and its held-out set)."""
    tool(script).main(["--out", str(tmp_path), *args])
    assert_same_files(tmp_path, SHIPPED[shipped], f"tools/make/{script}.py")


def test_make_bad_inputs_reproduces_the_shipped_corpus(tmp_path, tool):
    tool("make_bad_inputs").main(["--out", str(tmp_path / "bad_inputs")])
    script = "tools/make/make_bad_inputs.py"
    assert_same_files(tmp_path / "bad_inputs", SHIPPED["bad_inputs"], script)


@pytest.mark.parametrize("layout", ["default", "so100_block", "koch_block"])
def test_the_arms_rest_boxes_are_their_models(tool, layout):
    """``robots.Robot.rest_arm`` is what measure_rest.py measures on ManiSkill's model at the
    arm's rest (a row per link, widened to whole millimetres: within 1.5 mm on any machine);
    the SO-100's jaws rest 7.2 cm above the table 21-26 cm out, the Koch's 9.9 cm up."""
    from embodied_envs.robots import ROBOTS

    uid, rows = tool("measure_rest").rest_boxes(str(DATA / "layouts" / f"{layout}.json"))
    stored = np.array(ROBOTS[uid].rest_arm)
    assert stored.shape == (len(rows), 5), uid
    np.testing.assert_allclose(np.array([box for _, box in rows]), stored, atol=1.5e-3)
    jaws = {"so100": ("Fixed_Jaw", 0.072), "koch-v1.1": ("link_6", 0.099)}.get(uid)
    if jaws:
        assert dict(rows)[jaws[0]][4] == pytest.approx(jaws[1], abs=1.5e-3)


def test_a_changed_file_is_named(tmp_path):
    """The comparison itself: a value changed, a file missing, a file added."""
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.json").write_text('{"z": 0.76}\n')
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "x.json").write_text('{"z": 0.761}\n')
    with pytest.raises(AssertionError, match=r"does not reproduce \['x.json'\].*/z"):
        assert_same_files(tmp_path / "a", tmp_path / "b", "s")
    (tmp_path / "b" / "y.json").write_text("")
    with pytest.raises(AssertionError, match=r"writes \[\] and not \['y.json'\]"):
        assert_same_files(tmp_path / "a", tmp_path / "b", "s")


RING = ROOT / "tests" / "data" / "zoo" / "assets" / "ring" / "mesh" / "ring_collision.obj"
BALL = ROOT / "tests" / "data" / "zoo" / "assets" / "ball" / "mesh" / "ball_collision.obj"


def rewrite_obj(src, dst, change) -> None:
    """``src`` written to ``dst`` with ``change(vertices, faces)`` applied to each object's
    vertices (metres, N x 3) and 0-based faces; returns the new pair."""
    out, first = [], 0
    for lines, verts, faces in parse_obj(src.read_bytes()):
        v, f = change(verts * OBJ_STEP, faces.copy()) if len(verts) else (verts, faces)
        out += lines[:1] if lines and lines[0].startswith("o ") else []
        out += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
        out += lines[1:] if lines and lines[0].startswith("o ") else lines
        out += [f"f {a + first + 1} {b + first + 1} {c + first + 1}" for a, b, c in f]
        first += len(v)
    dst.write_text("\n".join(out) + "\n")


def shuffled(v, f):
    """Another vertex order and face order, each face started at another corner: what qhull
    gives on another processor."""
    rng = np.random.default_rng(0)
    order = rng.permutation(len(v))
    new = np.argsort(order)
    faces = np.roll(new[f], 1, axis=1)[rng.permutation(len(f))]
    return v[order], faces


def other_diagonal(v, f):
    """A flat quad (two coplanar faces sharing an edge) split along its other diagonal: the
    same surface."""
    mesh = trimesh.Trimesh(v, f, process=False)
    flat = int(np.argmin(mesh.face_adjacency_angles))
    (i, j), (a, b) = mesh.face_adjacency[flat], mesh.face_adjacency_edges[flat]
    assert mesh.face_adjacency_angles[flat] < 1e-4, "a flat quad"
    c = next(x for x in f[i] if x not in (a, b))
    d = next(x for x in f[j] if x not in (a, b))
    ring_i = list(f[i])
    k = ring_i.index(c)
    a, b = ring_i[(k + 1) % 3], ring_i[(k + 2) % 3]  # f[i] = (c, a, b) as oriented
    f[i], f[j] = (c, a, d), (c, d, b)
    return v, f


CHANGES = {  # a real change of a generator's mesh -> what the comparison says
    "a vertex moved 0.1 mm": (lambda v, f: (v + (np.arange(len(v)) == 3)[:, None] * 1e-4, f),
                              "matches 0 vertices"),
    "a face flipped": (lambda v, f: (v, np.vstack([f[:1, ::-1], f[1:]])), "faces differ"),
    "a face dropped": (lambda v, f: (v, f[1:]), "faces"),
    "the part 0.5 mm bigger": (lambda v, f: (v * 1.01, f), "matches 0 vertices"),
    "a face on another corner": (lambda v, f: (v, rewired(f)), "faces differ"),
}  # fmt: skip


def rewired(f):
    f = f.copy()
    f[0, 2] = min(set(range(f.max() + 1)) - set(f[0]))
    return f


@pytest.mark.parametrize("mesh", [RING, BALL], ids=["ring (flat sides)", "ball"])
def test_meshes_compare_by_geometry_and_a_real_change_is_caught(tmp_path, mesh):
    """Another vertex and face order, flat sides split along the other diagonal, and every
    coordinate one written step (1 um) off reproduce the mesh; each real change is named."""
    same = tmp_path / "same.obj"
    rewrite_obj(mesh, same, shuffled)
    assert same.read_bytes() != mesh.read_bytes() and differ(same, mesh) is None
    rewrite_obj(mesh, same, lambda v, f: (v + OBJ_STEP * np.sign(v - v.mean(0)), f))
    assert differ(same, mesh) is None, "one step of the written precision"
    if mesh == RING:
        rewrite_obj(mesh, same, other_diagonal)
        assert same.read_bytes() != mesh.read_bytes() and differ(same, mesh) is None
    for what, (change, words) in CHANGES.items():
        changed = tmp_path / "changed.obj"
        rewrite_obj(mesh, changed, change)
        assert words in (differ(changed, mesh) or ""), what
    two_steps = tmp_path / "two_steps.obj"
    rewrite_obj(mesh, two_steps, lambda v, f: (v + 2 * OBJ_STEP, f))
    assert "matches 0 vertices" in differ(two_steps, mesh)


def test_ply_and_json_compare_by_value_and_a_real_change_is_caught(tmp_path):
    room = DATA / "assets" / "background" / "mesh_model.ply"
    header, elements = parse_ply(room.read_bytes())
    body = room.read_bytes()[: -sum(e.nbytes for e in elements.values())]

    def write(vertex, face=elements["face"]):
        path = tmp_path / "room.ply"
        path.write_bytes(body + vertex.tobytes() + face.tobytes())
        return path

    v = elements["vertex"].copy()
    v["x"] = np.nextafter(v["x"], np.float32(np.inf))  # a float32 step: another processor
    assert differ(write(v), room) is None
    v["x"] += np.float32(1e-4)  # 0.1 mm
    assert "vertex x: values differ by up to 0.0001" in differ(write(v), room)
    v = elements["vertex"].copy()
    v["red"][5] += 1
    assert "vertex red" in differ(write(v), room)
    face = elements["face"].copy()
    face["vertex_indices"][0] = face["vertex_indices"][0][::-1]
    assert "face vertex_indices" in differ(write(elements["vertex"], face), room)
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text('{"p": [0.1, 0.2], "n": "x"}')
    b.write_text('{"p": [0.1, 0.20000000000000004], "n": "x"}')
    assert differ(a, b) is None
    b.write_text('{"p": [0.1, 0.2001], "n": "x"}')
    assert differ(a, b) == "value differs at /p/1"
    b.write_text('{"p": [0.1, 0.2], "n": "y"}')
    assert differ(a, b) == "value differs at /n"
