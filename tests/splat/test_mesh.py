"""mesh_to_splat: Gaussians on the surface, flat along its normal, coloured like it."""

import math

import numpy as np
import pytest
import torch
import trimesh

from embodied_envs.splat import mesh_to_splat
from embodied_envs.splat.mesh import FLAT_SCALE, OPACITY
from embodied_envs.splat.model import quat_wxyz_to_matrix
from embodied_envs.splat.sh import SH_C0


def two_colour_box() -> trimesh.Trimesh:
    """A 0.4 x 0.2 x 0.1 box whose +z face is red and every other face blue."""
    box = trimesh.creation.box(extents=(0.4, 0.2, 0.1))
    colors = np.tile([0, 0, 255, 255], (len(box.faces), 1)).astype(np.uint8)
    colors[box.face_normals[:, 2] > 0.9] = [255, 0, 0, 255]
    box.visual = trimesh.visual.ColorVisuals(box, face_colors=colors)
    return box


def test_gaussians_lie_on_the_surface_flat_and_coloured_like_it():
    box = two_colour_box()
    splat = mesh_to_splat(box, 4000, seed=1)
    means = splat.means.numpy()
    # on the surface: at least one coordinate at the half extent, none beyond it
    half = np.array([0.2, 0.1, 0.05])
    assert np.all(np.abs(means) <= half + 1e-6)
    assert np.all(np.min(np.abs(np.abs(means) - half), axis=1) < 1e-6)
    # the third axis of each Gaussian's frame is its face normal; that axis has FLAT_SCALE
    rot = quat_wxyz_to_matrix(splat.unit_quats_wxyz).numpy()
    normals = splat.normals.numpy()
    assert np.allclose(np.abs(np.einsum("ni,ni->n", rot[:, :, 2], normals)), 1.0, atol=1e-5)
    assert np.allclose(splat.scales[:, 2].numpy(), FLAT_SCALE)
    assert np.allclose(splat.opacities.numpy(), OPACITY, atol=1e-6)
    # colour from the face under the Gaussian: red on top, blue elsewhere
    rgb = 0.5 + SH_C0 * splat.sh[:, 0].numpy()  # the degree-0 colour 3DGS renders
    top = normals[:, 2] > 0.9
    assert np.allclose(rgb[top], [1, 0, 0], atol=1e-2)
    assert np.allclose(rgb[~top], [0, 0, 1], atol=1e-2)


def test_sampling_is_area_weighted_and_seeded():
    box = two_colour_box()
    splat = mesh_to_splat(box, 20000, seed=2)
    normals = splat.normals.numpy()
    # the +z face holds 0.08 m^2 of the box's 0.28 m^2
    frac = (normals[:, 2] > 0.9).mean()
    expected = 0.4 * 0.2 / (2 * (0.4 * 0.2 + 0.4 * 0.1 + 0.2 * 0.1))
    assert abs(frac - expected) < 4.5 * math.sqrt(expected * (1 - expected) / 20000)
    again = mesh_to_splat(box, 20000, seed=2)
    other = mesh_to_splat(box, 20000, seed=3)
    assert torch.equal(splat.means, again.means) and torch.equal(splat.sh, again.sh)
    assert not torch.equal(splat.means, other.means)


def test_visible_from_samples_only_faces_turned_to_the_point():
    box = two_colour_box()
    splat = mesh_to_splat(box, 2000, seed=0, visible_from=(0.0, 0.0, 5.0))
    assert np.all(splat.normals.numpy()[:, 2] > 0.9)  # only the top faces the point above


def test_bad_counts_and_meshes_are_refused():
    box = two_colour_box()
    with pytest.raises(ValueError, match="count must be positive"):
        mesh_to_splat(box, 0)
    with pytest.raises(ValueError, match="no \\(visible\\) faces"):
        mesh_to_splat(box, 10, visible_from=(0.0, 0.0, 0.0))  # inside: every face turns away
