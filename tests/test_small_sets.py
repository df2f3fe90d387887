"""The small arms' drawn held-out sets (tools/make/make_small_sets.py, issue 59): one seed
writes the same set every time (the shipped development set ``tests/data/small_sets/dev1`` is
``--draw 1``), on a table of its own with the robot at its top's height, its objects' sizes
across the jaws within ``--sizes``, every layout read, checked and one made into the env."""

import importlib.util
import json
import os
import sys

import gymnasium as gym
import numpy as np
import pytest
from conftest import DATA, ROOT
from data_compare import OBJ_STEP, differ, json_differ, parse_obj
from scipy.spatial import ConvexHull

import embodied_envs  # noqa: F401

TOOLS = ROOT / "tools" / "make"
DEV1 = ROOT / "tests" / "data" / "small_sets" / "dev1"
TOL = 5e-4  # m: a round part's facets inside its drawn diameter


@pytest.fixture(scope="module")
def sets():
    """make_small_sets.py as a module (tools/make/ on the path while it loads its helpers)."""
    before = set(sys.modules)
    sys.path.insert(0, str(TOOLS))
    try:
        path = TOOLS / "make_small_sets.py"
        spec = importlib.util.spec_from_file_location("make_small_sets", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(TOOLS))
        for name in set(sys.modules) - before:
            if (getattr(sys.modules[name], "__file__", None) or "").startswith(str(TOOLS)):
                del sys.modules[name]


@pytest.fixture(scope="module")
def written(sets, tmp_path_factory):
    """``--draw 1`` twice (folders at the same depth) and with ``--sizes 0.02 0.03``."""
    root = tmp_path_factory.mktemp("sets")
    for name, extra in (("a", []), ("b", []), ("narrow", ["--sizes", "0.02", "0.03"])):
        sets.main(["--draw", "1", "--out", str(root / name / "dev1"), *extra])
    return root


def files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())


def test_a_seed_writes_the_same_bytes_and_the_shipped_set(written):
    a, b = written / "a" / "dev1", written / "b" / "dev1"
    assert files(a) == files(b) and files(a) == files(DEV1)
    assert not [f for f in files(a) if (a / f).read_bytes() != (b / f).read_bytes()]
    assert not list(written.glob("*/.*")), "a temporary folder was left"
    why = {}
    for f in files(a):
        if f.startswith("layouts/"):  # the shipped room's path: from where the set was written
            got, want = (json.loads((folder / f).read_text()) for folder in (a, DEV1))
            for data in (got, want):
                data["assets"].pop("background")
            why[f] = json_differ(got, want, f)
        else:
            why[f] = differ(a / f, DEV1 / f)
    assert not {k: v for k, v in why.items() if v}, "make_small_sets.py --draw 1 != dev1"


def narrowest(points: np.ndarray) -> float:
    """The least width of a 2D point set's convex hull."""
    hull = ConvexHull(points)
    along = points @ hull.equations[:, :2].T
    return float((along.max(0) - along.min(0)).min())


@pytest.mark.parametrize("name, lo, hi", [("a", 0.015, 0.04), ("narrow", 0.02, 0.03)])
def test_sizes_across_the_jaws_lie_in_the_range_asked(written, name, lo, hi):
    out = written / name / "dev1"
    drawn = json.loads((out / "set.json").read_text())
    assert drawn["sizes"] == [lo, hi]
    movers = {n: o for n, o in drawn["objects"].items()
              if o["family"] not in ("bowl", "tray", "globe", "carton", "tin")}  # fmt: skip
    picks = {o["family"] for n, o in movers.items() if n != "place_cube"}
    assert len(movers) == 7 and len(picks) == 6  # six families, no repeats; the place's cube
    for node, obj in movers.items():
        mesh = out / "assets" / node / "mesh" / f"{node}_collision.obj"
        # stored Y-up: the footprint is (x, -z); the thinnest part's narrowest footprint width
        parts = [v * OBJ_STEP for _, v, _ in parse_obj(mesh.read_bytes()) if len(v)]
        width = min(narrowest(v[:, [0, 2]]) for v in parts)
        assert lo - TOL <= width <= hi + TOL, (node, width)
        assert 300 <= obj["density"] <= 1200 and obj["mass"] > 0


def test_the_table_is_its_own_and_the_robot_stands_at_its_top(written, sets):
    out = written / "a" / "dev1"
    shipped = {p.name for p in (DATA / "assets").iterdir()}
    layouts = sorted((out / "layouts").glob("*.json"))
    assert len(layouts) == 14
    assert {json.loads(p.read_text())["relation"]["robot"] for p in layouts} == {
        "so100", "koch-v1.1"}  # fmt: skip
    for path in layouts:
        data = json.loads(path.read_text())
        rel = data["relation"]
        table = rel["context"]
        folder = (path.parent / data["assets"][table]).resolve()
        assert table not in shipped and folder.parent == out / "assets"
        assert 1 <= len(set(rel["distractor_objs"]) & {"globe", "carton", "tin"}) <= 2
        stored = np.concatenate([v for _, v, _ in parse_obj(
            (folder / "mesh" / f"{table}_collision.obj").read_bytes()) if len(v)]) * OBJ_STEP
        top = data["position"][table][2] + stored[:, 1].max()  # Y-up: z is the stored y
        assert 0.68 <= top <= 0.80
        assert data["position"][rel["robot"]][2] == pytest.approx(top, abs=1e-6)
    sets.check(out / "layouts", simulate=False)  # read, file poses, jaws and payload


def test_a_drawn_layout_makes_an_env_whose_top_is_the_robots_spot():
    os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
    path = next(iter(sorted((DEV1 / "layouts").glob("koch_*_tray.json")) +
                     sorted((DEV1 / "layouts").glob("koch_*_bowl.json"))))  # fmt: skip
    spot = json.loads(path.read_text())["position"]["koch-v1.1"]
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), control_mode="pd_joint_pos")
    try:
        env.reset(seed=0)
        assert float(env.unwrapped.layout_scene.top_z[0]) == pytest.approx(spot[2], abs=1e-5)
    finally:
        env.close()
