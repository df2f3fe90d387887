"""``embodied-envs splat from-mesh``: a mesh file becomes a splat PLY on its surface, coloured
like it; bad input is one error line naming the file, and nothing is written."""

import numpy as np
import pytest
import trimesh

from embodied_envs.cli.main import main
from embodied_envs.splat import read_ply
from embodied_envs.splat.sh import SH_C0

RED = (200, 40, 40, 255)


@pytest.fixture
def box_file(tmp_path):
    """A red 0.4 x 0.2 x 0.1 m box, off the origin, as a PLY mesh file."""
    box = trimesh.creation.box(extents=(0.4, 0.2, 0.1))
    box.apply_translation((1.0, -2.0, 0.5))
    box.visual.face_colors = RED
    path = tmp_path / "box.ply"
    box.export(path)
    return path, box.bounds


def test_from_mesh_writes_gaussians_on_the_mesh_with_its_colour(tmp_path, box_file, capsys):
    mesh, bounds = box_file
    before = mesh.read_bytes()
    out = tmp_path / "out" / "box_splat.ply"
    assert main(["splat", "from-mesh", str(mesh), "--out", str(out), "--count", "500"]) == 0
    assert f"wrote {out}: 500 Gaussians" in capsys.readouterr().out
    splat = read_ply(out)
    assert len(splat) == 500
    means = splat.means.numpy()
    assert np.all(means >= bounds[0] - 1e-5) and np.all(means <= bounds[1] + 1e-5)
    # on the surface: each point on at least one face of the box
    on_face = np.isclose(means, bounds[0], atol=1e-5) | np.isclose(means, bounds[1], atol=1e-5)
    assert on_face.any(axis=1).all()
    colour = splat.sh[:, 0].numpy() * SH_C0 + 0.5
    np.testing.assert_allclose(colour, np.broadcast_to(np.array(RED[:3]) / 255, colour.shape),
                               atol=1e-3)  # fmt: skip
    assert splat.normals is None  # not asked for (--normals)
    assert mesh.read_bytes() == before
    assert sorted(p.name for p in out.parent.iterdir()) == ["box_splat.ply"]  # no temporary left


def test_from_mesh_visible_from_samples_only_the_faces_facing_the_point(tmp_path, box_file):
    mesh, bounds = box_file
    out = tmp_path / "top.ply"
    above = ["--visible-from", "1.0", "-2.0", "10.0"]  # far above: only the top face faces it
    assert main(["splat", "from-mesh", str(mesh), "--out", str(out), "--count", "200", *above]) == 0
    means = read_ply(out).means.numpy()
    np.testing.assert_allclose(means[:, 2], bounds[1][2], atol=1e-5)


@pytest.mark.parametrize("bad", ["missing", "not_a_mesh", "points"])
def test_from_mesh_refuses_bad_input_in_one_line(tmp_path, capsys, bad):
    mesh = tmp_path / f"{bad}.ply"
    if bad == "not_a_mesh":
        mesh.write_text("this is not a mesh\n")
    elif bad == "points":
        trimesh.PointCloud(np.random.default_rng(0).random((10, 3))).export(mesh)
    out = tmp_path / "out.ply"
    assert main(["splat", "from-mesh", str(mesh), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {mesh}: ") and "Fix:" in err, err
    assert not out.exists()


def test_from_mesh_count_must_be_positive(tmp_path, box_file, capsys):
    mesh, _ = box_file
    with pytest.raises(SystemExit) as e:
        main(["splat", "from-mesh", str(mesh), "--out", str(tmp_path / "o.ply"), "--count", "0"])
    assert e.value.code == 2 and "0 is not a positive integer" in capsys.readouterr().err
