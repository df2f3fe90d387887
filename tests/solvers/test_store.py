"""The expert's per-asset results kept between runs (``solvers/store.py``): read back bit for
bit, computed once, named anew by any changed input, recomputed from an unreadable file, and
never a failure when the cache folder cannot be written."""

import dataclasses
import os

import numpy as np
import pytest
from conftest import ROOT

from embodied_envs.layout import parse_urdf
from embodied_envs.layout.assets import FileCache
from embodied_envs.layout.collision import CACHE_ENV
from embodied_envs.solvers import grasps as grasps_module
from embodied_envs.solvers import store
from embodied_envs.solvers.grasps import GraspConfig, Grasps, asset_grasps
from embodied_envs.solvers.gripper import GripperModel

ZOO = ROOT / "tests" / "data" / "zoo" / "assets"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty cache folder, and an empty in-process cache of asset values."""
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(grasps_module, "ASSET_FILES", FileCache())
    return tmp_path / "cache" / "expert"


def counted(monkeypatch):
    """Counts the grasp syntheses run (``grasps._compute``)."""
    calls = []
    compute = grasps_module._compute
    monkeypatch.setattr(
        grasps_module, "_compute", lambda *a: calls.append(a) or compute(*a)
    )
    return calls


def assert_same(a: Grasps, b: Grasps) -> None:
    for f in dataclasses.fields(Grasps):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, tuple):
            assert len(x) == len(y) and all(
                u.dtype == v.dtype and np.array_equal(u, v) for u, v in zip(x, y, strict=True)
            ), f.name
        elif x is None:
            assert y is None, f.name
        else:
            assert x.dtype == y.dtype and np.array_equal(x, y), f.name


def test_grasps_are_computed_once_and_read_back_bit_for_bit(cache, monkeypatch):
    spec = parse_urdf(ZOO / "t_shape" / "t_shape.urdf")
    calls = counted(monkeypatch)
    first = asset_grasps(spec)
    assert len(calls) == 1 and len(list(cache.glob("grasps-*.npz"))) == 1
    monkeypatch.setattr(grasps_module, "ASSET_FILES", FileCache())  # a new process
    again = asset_grasps(spec)
    assert len(calls) == 1, "read from the cache folder, not synthesised again"
    assert_same(first, again)
    assert len(again) > 100 and again.annotated is None and len(again.planes) >= 1
    other = asset_grasps(spec, GraspConfig(approaches=8))  # other settings: another result
    assert len(calls) == 2 and len(list(cache.glob("grasps-*.npz"))) == 2
    assert len(other) != len(first), "fewer approaches: other grasps"


def test_a_result_is_named_by_its_files_settings_and_code(tmp_path):
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\n")
    modules = ("embodied_envs.solvers.grasps",)
    name = store.result_name("grasps", (mesh, None), (GraspConfig(), GripperModel()), modules)
    assert name == store.result_name("grasps", (mesh, None), (GraspConfig(), GripperModel()),
                                     modules)  # fmt: skip
    assert name.startswith("grasps-")
    changed = [
        store.result_name("grasps", (mesh, mesh), (GraspConfig(), GripperModel()), modules),
        store.result_name("grasps", (mesh, None), (GraspConfig(margin=0.007), GripperModel()),
                          modules),  # fmt: skip
        store.result_name("grasps", (mesh, None), (GraspConfig(), GripperModel()),
                          modules + ("embodied_envs.solvers.gripper",)),  # fmt: skip
    ]
    mesh.write_text("v 0 0 1\n")  # the same file name, other bytes
    changed.append(
        store.result_name("grasps", (mesh, None), (GraspConfig(), GripperModel()), modules)
    )
    assert len({name, *changed}) == 5


def test_an_unreadable_file_is_computed_again_and_rewritten(cache, monkeypatch):
    spec = parse_urdf(ZOO / "t_shape" / "t_shape.urdf")
    calls = counted(monkeypatch)
    first = asset_grasps(spec)
    (path,) = cache.glob("grasps-*.npz")
    good = path.read_bytes()
    for k, bad in enumerate((b"not an npz", b"", good[: len(good) // 2])):  # cut short too
        path.write_bytes(bad)
        monkeypatch.setattr(grasps_module, "ASSET_FILES", FileCache())
        again = asset_grasps(spec)
        assert len(calls) == 2 + k
        assert_same(first, again)
        assert path.read_bytes()[:2] == b"PK", "rewritten as an npz (a zip)"


def test_a_cache_folder_that_cannot_be_written_costs_only_the_time(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setenv(CACHE_ENV, str(blocker))
    made = store.cached("x-1", lambda: Grasps(*[np.zeros(1)] * 8, planes=()), Grasps)
    assert len(made) == 1 and made.planes == ()
    assert sorted(os.listdir(tmp_path)) == ["file"]
