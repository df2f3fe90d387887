"""A thing set in a hollow rests on its floor, as the camera sees it: an open-topped box written
as a bare surface, a mug written as two objects (a concave body and a handle), a tray with a
1 cm recess in a 3 cm base. Each is loaded as a user's asset (its collision mesh its visual
mesh's shape), and a 2 cm block is dropped in it in SAPIEN on the collision parts the loader
chose; kept as written (``EMBODIED_ENVS_DECOMPOSE=0``) the simulator's hulls fill the hollow.
The shipped mug, whose collision is made hollow, is dropped into as shipped."""

import warnings

import numpy as np
import pytest
import sapien
from conftest import DATA
from shapes import mug_objects, open_box, tray, write_asset

from embodied_envs.layout import asset_geometry, parse_urdf
from embodied_envs.layout import collision as col
from embodied_envs.layout.hollow import HOLLOW_TOLERANCE, surface_tops
from embodied_envs.scene.builder import asset_density

BLOCK = 0.02  # m: the side of the block dropped in
# case: (visual meshes, collision written as one object, where the block is dropped (x, y in the
# object's frame: the hollow's centre), how deep the simulator's hulls fill it, m)
CASES = {
    "open_box": ([open_box()], True, (0.0, 0.0), 0.08),
    "two_object_mug": (mug_objects(), False, (-0.015, 0.0), 0.086),
    "shallow_tray": ([tray()], True, (0.0, 0.0), 0.01),
}


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """Each case's URDF, decomposed once into a cache of this module's own."""
    root = tmp_path_factory.mktemp("hollows")
    urdfs = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(col.CACHE_ENV, str(root / "cache"))
        mp.delenv(col.OPT_OUT_ENV, raising=False)
        col._convex_collision.cache_clear()
        for name, (meshes, one_object, _, _) in CASES.items():
            urdfs[name] = write_asset(root / "assets", name, meshes, one_object=one_object)
            assert parse_urdf(urdfs[name]).collision.source is not None, "not decomposed"
        yield urdfs, root / "cache"
    col._convex_collision.cache_clear()


def resting_gap(spec, xy) -> float:
    """How far above the visual floor at ``xy`` a block dropped there rests, m: the asset
    static at the origin, built as scene/builder.py builds it, one simulated second."""
    scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
    scene.set_timestep(1 / 200)
    material = sapien.physx.PhysxMaterial(0.7, 0.6, 0.05)
    builder = scene.create_actor_builder()
    builder.add_multiple_convex_collisions_from_file(
        str(spec.collision.path),
        pose=spec.collision.sapien_pose(),
        scale=spec.collision.scale,
        material=material,
        density=asset_density(spec),
        decomposition="none",
    )
    builder.build_static()
    visual = col.load_mesh(spec.visual.path)
    floor = surface_tops(spec.visual.to_link_frame(visual.vertices)[visual.faces], [xy])[0][0]
    top = col.solid_top(list(asset_geometry(spec).parts), xy)
    builder = scene.create_actor_builder()
    builder.add_box_collision(half_size=[BLOCK / 2] * 3, material=material)
    block = builder.build()
    block.set_pose(sapien.Pose([xy[0], xy[1], max(floor, top) + BLOCK / 2 + 0.005]))
    for _ in range(200):
        scene.step()
    body = block.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    assert np.linalg.norm(body.linear_velocity) < 1e-3, "still moving"
    return float(block.pose.p[2]) - BLOCK / 2 - float(floor)


@pytest.mark.parametrize("name", list(CASES))
def test_a_block_set_in_the_hollow_rests_on_its_visual_floor(assets, name, monkeypatch):
    urdfs, cache = assets
    monkeypatch.setenv(col.CACHE_ENV, str(cache))
    col._convex_collision.cache_clear()
    xy, depth = CASES[name][2], CASES[name][3]
    assert resting_gap(parse_urdf(urdfs[name]), xy) == pytest.approx(0.0, abs=HOLLOW_TOLERANCE)
    # as written, the simulator's hulls fill it: the block rests on the filled top
    monkeypatch.setenv(col.OPT_OUT_ENV, "0")
    col._convex_collision.cache_clear()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the opt-out's own warning
        kept = parse_urdf(urdfs[name])
    assert kept.collision.source is None
    assert resting_gap(kept, xy) == pytest.approx(depth, abs=HOLLOW_TOLERANCE)
    col._convex_collision.cache_clear()


def test_a_block_set_in_the_shipped_mug_rests_on_its_visual_floor():
    """The shipped mug's collision (a base, wall pieces and the handle) leaves its hollow open:
    kept as shipped, a block dropped at the cup's centre rests on the visual floor, and the
    mug is loaded without a word about a filled hollow."""
    urdf = DATA / "assets" / "mug" / "mug.urdf"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        spec = parse_urdf(urdf)
    assert spec.collision.source is None  # its own collision file, not decomposed
    cup = (asset_geometry(spec).vertices[:, 0].min() + 0.038, 0.0)  # its axis, 38 mm in
    assert resting_gap(spec, cup) == pytest.approx(0.0, abs=HOLLOW_TOLERANCE)
