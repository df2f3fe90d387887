import json
import shutil
import subprocess
import sys
import time

import pytest
from conftest import DATA, LAYOUTS, write_layout
from placement_checks import check_constraints

from embodied_envs.layout import PlacementError, load_layout
from embodied_envs.layout.placement import place


@pytest.mark.parametrize("path", LAYOUTS, ids=[p.stem for p in LAYOUTS])
def test_constraints_hold_over_200_seeds(path):
    layout = load_layout(path)
    for seed in range(200):
        bad = check_constraints(place(layout, seed))
        assert not bad, f"seed {seed}: {bad}"


def test_the_oracle_reads_the_limits_it_checks():
    """The independent check takes its numbers from PlacementLimits: layouts placed with wider
    limits than the defaults break the default rules it checks, and pass their own."""
    from embodied_envs.layout import PlacementLimits

    wide = PlacementLimits(reach_max=1.2, max_heading_deg=120.0, clearance=0.0)
    layouts = [place(load_layout(LAYOUTS[0]), s, wide) for s in range(40)]
    assert all(check_constraints(x, wide) == [] for x in layouts)
    broken = [p for x in layouts for p in check_constraints(x)]
    assert any("m from the robot" in p or "deg off the robot heading" in p for p in broken)


def test_same_seed_same_layout_different_seed_different():
    layout = load_layout(LAYOUTS[0])
    a, b, c = place(layout, 7), place(layout, 7), place(layout, 8)
    assert a.position == b.position
    assert a.position["can"] != c.position["can"]
    assert layout.position != a.position  # the input is not modified
    assert load_layout(LAYOUTS[0]).position == layout.position


def test_same_seed_same_layout_across_processes():
    code = (
        "import json,sys; from embodied_envs.layout import load_layout;"
        "from embodied_envs.layout.placement import place;"
        f"print(json.dumps(place(load_layout({str(LAYOUTS[0])!r}), 123).to_dict()['position']))"
    )
    outs = [
        subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        ).stdout
        for _ in range(2)
    ]
    here = place(load_layout(LAYOUTS[0]), 123).to_dict()["position"]
    assert json.loads(outs[0]) == json.loads(outs[1]) == here


def test_impossible_request_fails_fast_naming_object(tmp_path):
    data = json.loads((DATA / "layouts" / "default.json").read_text())
    data["assets"] = {k: str((DATA / "layouts" / v).resolve()) for k, v in data["assets"].items()}
    for i in range(40):  # forty bowls do not fit on the table
        name = f"bowl{i}"
        data["objs_mapping"][name] = "distractor_objs"
        data["relation"]["distractor_objs"].append(name)
        data["assets"][name] = data["assets"]["bowl"]
        data["position"][name] = [0, 0, 0, 0, 0, 0, 1]
        data["tree"]["table"].append([name, "ON"])
    d = tmp_path / "assets_copy"
    import shutil

    for i in range(40):
        shutil.copytree(DATA / "assets" / "bowl", d / f"bowl{i}")
        (d / f"bowl{i}" / "bowl.urdf").rename(d / f"bowl{i}" / f"bowl{i}.urdf")
        data["assets"][f"bowl{i}"] = str(d / f"bowl{i}")
    layout = load_layout(write_layout(tmp_path, data), check_poses=False)  # all re-drawn
    t = time.perf_counter()
    with pytest.raises(PlacementError) as exc:
        place(layout, 0)
    assert time.perf_counter() - t < 10
    assert exc.value.node.startswith("bowl"), exc.value.node  # the table fills with bowls
    assert "no overlap" in str(exc.value)


def test_editing_only_the_collision_mesh_is_seen_by_placement(scene_copy):
    """Geometry caches are keyed on the URDF and on the collision mesh it names."""
    import os

    from embodied_envs.layout.placement import node_footprint, polygon_area

    layout = load_layout(scene_copy / "layouts" / "default.json")
    before = polygon_area(node_footprint(layout, "mug"))
    mesh = scene_copy / "assets" / "mug" / "mesh" / "mug_collision.obj"
    lines = []
    for line in mesh.read_text().splitlines():
        if line.startswith("v "):
            x, y, z = (2 * float(v) for v in line.split()[1:4])
            line = f"v {x} {y} {z}"
        lines.append(line)
    mesh.write_text("\n".join(lines) + "\n")
    later = mesh.stat().st_mtime + 5  # a new modification time even on coarse clocks
    os.utime(mesh, (later, later))
    after = polygon_area(node_footprint(layout, "mug"))
    assert after == pytest.approx(4 * before, rel=1e-6)


def test_cached_geometry_is_read_only_and_keyed_on_size_too(scene_copy):
    """The asset cache hands out shared arrays (read-only) and re-reads a file whose size
    changed even when its modification time was put back."""
    import os

    from embodied_envs.layout.placement import node_footprint, node_geometry, polygon_area

    layout = load_layout(scene_copy / "layouts" / "default.json")
    foot = node_footprint(layout, "mug")
    with pytest.raises(ValueError, match="read-only"):
        foot[0, 0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        node_geometry(layout, "mug").vertices[0, 0] = 1.0
    before = polygon_area(foot)
    mesh = scene_copy / "assets" / "mug" / "mesh" / "mug_collision.obj"
    stat = mesh.stat()
    lines = [
        "v " + " ".join(f"{3 * float(v):.9f}" for v in line.split()[1:4])
        if line.startswith("v ") else line
        for line in mesh.read_text().splitlines()
    ]  # fmt: skip
    mesh.write_text("\n".join(lines) + "\n")
    os.utime(mesh, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # the old time, a new size
    assert mesh.stat().st_size != stat.st_size
    assert polygon_area(node_footprint(layout, "mug")) == pytest.approx(9 * before, rel=1e-5)


def test_a_urdf_pointing_to_another_mesh_is_seen(scene_copy):
    """No stale URDF lookup: the collision mesh the URDF names now is the one used."""
    from embodied_envs.layout.placement import node_footprint, polygon_area

    layout = load_layout(scene_copy / "layouts" / "default.json")
    mug = polygon_area(node_footprint(layout, "mug"))
    box = polygon_area(node_footprint(layout, "cracker_box"))
    urdf = scene_copy / "assets" / "mug" / "mug.urdf"
    shutil.copy(
        scene_copy / "assets" / "cracker_box" / "mesh" / "cracker_box_collision.obj",
        scene_copy / "assets" / "mug" / "mesh" / "other.obj",
    )
    urdf.write_text(urdf.read_text().replace("mug_collision.obj", "other.obj"))
    got = polygon_area(node_footprint(layout, "mug"))
    assert got == pytest.approx(box, rel=1e-6) and got != pytest.approx(mug, rel=1e-3)
