import math

import numpy as np
import pytest
import torch
from reference import render_reference
from splat_helpers import random_splat

from embodied_envs.splat import PinholeCamera, pose_splat, render
from embodied_envs.splat import rasterizer as rast
from embodied_envs.splat.backend import resolve_backend
from embodied_envs.splat.model import GaussianSplat, quat_wxyz_to_matrix, sh_colors
from embodied_envs.splat.sh import SH_C0

TOL = 2.0 / 255.0


def reference(splat, cam, background=(0.0, 0.0, 0.0)):
    colors = sh_colors(splat, torch.as_tensor(cam.center, dtype=torch.float32))
    return render_reference(
        splat.means.double().numpy(),
        splat.unit_quats_wxyz.double().numpy(),
        splat.scales.double().numpy(),
        splat.opacities.double().numpy(),
        colors.double().numpy(),
        cam.world_to_cam,
        cam.fx,
        cam.fy,
        cam.cx,
        cam.cy,
        cam.width,
        cam.height,
        background,
    )


def assert_matches_reference(image, ref):
    rgb, alpha, depth = ref
    bad_rgb = np.abs(image.rgb.numpy() - rgb) > TOL
    assert bad_rgb.mean() <= 0.01, f"{bad_rgb.mean():.2%} of channel values differ"
    assert (np.abs(image.alpha.numpy() - alpha) > TOL).mean() <= 0.01
    bad_depth = np.abs(image.depth.numpy() - depth) > TOL * np.maximum(depth, 1.0)
    assert bad_depth.mean() <= 0.01


def single(mean, scale, opacity=0.8, color=(1.0, 0.5, 0.25)):
    def t(a):
        return torch.tensor([a], dtype=torch.float32)

    return GaussianSplat(
        means=t(mean),
        quats_wxyz=t([1.0, 0, 0, 0]),
        log_scales=t([math.log(scale)] * 3),
        opacity_logits=t(math.log(opacity / (1 - opacity))),
        sh=((t(color) - 0.5) / SH_C0)[:, None, :],
    )


CAMERAS = [
    dict(eye=(0.3, -2.5, 1.0), target=(0, 0, 0), width=48, height=40, fovy_deg=60),
    dict(eye=(0.0, 0.0, 0.2), target=(0, 1, 0.1), width=32, height=32, fovy_deg=90),  # inside
    dict(eye=(2.0, 1.0, -1.5), target=(0, 0, 0.2), width=40, height=56, fovy_deg=45),
]


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("cam_idx", range(len(CAMERAS)))
def test_matches_brute_force_reference(seed, cam_idx):
    splat = random_splat(seed, n=250, sh_degree=seed + 1)  # SH degree 1..3
    cam = PinholeCamera.look_at(**CAMERAS[cam_idx])
    image = rast.rasterize_torch(splat, cam, background=(0.1, 0.2, 0.3))
    ref = reference(splat, cam, background=(0.1, 0.2, 0.3))
    assert ref[1].mean() > 0.2, "scene should cover the image"
    assert_matches_reference(image, ref)


def test_matches_reference_when_pixels_saturate_and_chunks_are_small(monkeypatch):
    # a dense opaque stack: most pixels stop early, and tiny chunks exercise the live-pixel
    # culling between chunks
    rng = np.random.default_rng(5)
    n = 400
    s = random_splat(11, n=n)
    s = GaussianSplat(
        means=torch.tensor(
            rng.uniform([-0.6, -0.6, -1], [0.6, 0.6, 1], (n, 3)), dtype=torch.float32
        ),
        quats_wxyz=s.quats_wxyz,
        log_scales=s.log_scales,
        opacity_logits=torch.full((n,), 5.0),
        sh=s.sh,
    )
    cam = PinholeCamera.look_at(
        (0, 0, 3), (0, 0, 0), up=(0, 1, 0), width=40, height=40, fovy_deg=30
    )
    monkeypatch.setattr(rast, "MAX_PAIRS_PER_CHUNK", 700)
    image = rast.rasterize_torch(s, cam)
    ref = reference(s, cam)
    assert (ref[1] > 0.99).mean() > 0.3, "many pixels should reach the stop rule"
    assert_matches_reference(image, ref)
    # the stop rule leaves T >= 1e-4 where it applies; it shows exactly in alpha
    np.testing.assert_allclose(image.alpha.numpy(), ref[1], atol=2e-5)


def test_one_isotropic_gaussian_has_the_expected_peak_and_footprint():
    f_deg, size, dist, scale, opacity = 60.0, 64, 2.0, 0.05, 0.8
    cam = PinholeCamera.look_at(
        (0, 0, dist), (0, 0, 0), up=(0, 1, 0), width=size, height=size, fovy_deg=f_deg
    )
    image = rast.rasterize_torch(single((0, 0, 0), scale, opacity), cam)
    f = size / (2 * math.tan(math.radians(f_deg) / 2))
    var = (f * scale / dist) ** 2 + rast.LOW_PASS  # screen variance, px^2
    # pixel centres relative to the projected centre (32, 32)
    d = np.arange(size) + 0.5 - size / 2
    q = (d[None, :] ** 2 + d[:, None] ** 2) / var
    expected = np.where(q <= 9, np.minimum(0.99, opacity * np.exp(-q / 2)), 0.0)
    expected = np.where(expected >= 1 / 255, expected, 0.0)
    np.testing.assert_allclose(image.alpha.numpy(), expected, atol=1e-5)
    assert image.alpha.max().item() == pytest.approx(opacity * math.exp(-0.25 / var), rel=1e-4)
    covered = int((image.alpha > 0).sum())
    assert abs(covered - math.pi * 9 * var) < 0.1 * math.pi * 9 * var
    # colour is premultiplied by alpha; depth is alpha x distance
    np.testing.assert_allclose(image.rgb.numpy()[..., 0], expected, atol=1e-5)
    np.testing.assert_allclose(image.depth.numpy(), expected * dist, atol=1e-4)
    finite = torch.isfinite(image.surface_depth(0.5))
    assert finite.any() and torch.allclose(
        image.surface_depth(0.5)[finite], torch.tensor(dist), atol=1e-4
    )


@pytest.mark.parametrize("z", [-1.0, 0.005])
def test_gaussians_behind_or_at_the_camera_render_nothing(z):
    cam = PinholeCamera.look_at((0, 0, 0), (0, 0, -1), up=(0, 1, 0), width=32, height=32)
    # camera looks along -z; a Gaussian at world z = +1 is behind it, one at -0.005 too near
    image = rast.rasterize_torch(single((0, 0, -z), 0.3, 0.99), cam, background=(0.2, 0.2, 0.2))
    assert image.alpha.abs().max().item() == 0.0
    assert torch.allclose(image.rgb, torch.tensor(0.2))


def test_gaussian_beside_the_camera_does_not_smear_over_the_image():
    cam = PinholeCamera.look_at(
        (0, 0, 0), (0, 0, -1), up=(0, 1, 0), width=32, height=32, fovy_deg=60
    )
    # just in front of the camera plane and far to the side: outside the 1.3x frustum
    image = rast.rasterize_torch(single((1.0, 0.0, -0.05), 0.2, 0.99), cam)
    assert image.alpha.max().item() == 0.0


def test_translation_along_camera_x_shifts_the_image_by_f_dx_over_z():
    cam = PinholeCamera.look_at((0, 0, 2), (0, 0, 0), up=(0, 1, 0), width=64, height=64)
    s = single((0, 0, 0), 0.04, 0.9)
    moved = pose_splat(s, torch.tensor([0.25, 0.0, 0.0]), torch.tensor([1.0, 0, 0, 0]))

    def centroid(img):
        a = img.alpha.numpy()
        return (a * (np.arange(64) + 0.5)[None, :]).sum() / a.sum()

    shift = centroid(rast.rasterize_torch(moved, cam)) - centroid(rast.rasterize_torch(s, cam))
    # camera x (image right) is world +x here
    assert shift == pytest.approx(cam.fx * 0.25 / 2.0, abs=0.05)


def test_posed_splat_seen_by_a_camera_equals_the_splat_seen_by_the_moved_camera():
    splat = random_splat(3, n=150, sh_degree=2)
    q = torch.tensor([0.8, 0.2, -0.3, 0.4])
    q = q / q.norm()
    t = torch.tensor([0.3, -0.2, 0.5])
    cam = PinholeCamera.look_at((0.5, -3, 1.5), (0.3, 0, 0.5), width=40, height=40)
    posed = render(pose_splat(splat, t, q), cam, backend="torch")
    pose = np.eye(4)
    pose[:3, :3] = quat_wxyz_to_matrix(q[None].double())[0].numpy()
    pose[:3, 3] = t.numpy()
    moved_cam = PinholeCamera(
        cam.world_to_cam @ pose, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy
    )
    original = render(splat, moved_cam, backend="torch")
    assert original.alpha.mean() > 0.2
    assert (np.abs(posed.rgb.numpy() - original.rgb.numpy()) > TOL).mean() <= 0.01
    np.testing.assert_allclose(posed.depth.numpy(), original.depth.numpy(), atol=1e-3)


def test_degree_one_sh_colour_depends_on_view_direction():
    sh = torch.zeros((1, 4, 3))
    sh[0, 3, 0] = 1.0  # red varies with -x of the view direction
    s = GaussianSplat(
        torch.zeros((1, 3)), torch.tensor([[1.0, 0, 0, 0]]), torch.zeros((1, 3)), torch.zeros(1), sh
    )
    from_left = sh_colors(s, torch.tensor([-2.0, 0, 0]))  # view direction +x
    from_right = sh_colors(s, torch.tensor([2.0, 0, 0]))  # view direction -x
    c1 = 0.4886025119029199
    assert from_left[0, 0].item() == pytest.approx(0.5 - c1)
    assert from_right[0, 0].item() == pytest.approx(0.5 + c1)
    # posing rotates view directions back: turned 180 deg about z, the sides swap
    turned = pose_splat(s, torch.zeros(3), torch.tensor([0.0, 0, 0, 1]))
    assert sh_colors(turned, torch.tensor([-2.0, 0, 0]))[0, 0].item() == pytest.approx(0.5 + c1)


def test_backend_choice_is_explicit():
    assert resolve_backend("torch") == "torch"
    with pytest.raises(ValueError, match="unknown splat backend"):
        resolve_backend("optix")
    if not torch.cuda.is_available():
        assert resolve_backend("auto") == "torch"
        with pytest.raises(ValueError, match='backend "gsplat" cannot run here'):
            resolve_backend("gsplat")


def test_one_call_renders_many_cameras_as_each_alone(monkeypatch):
    """A batched camera argument gives, per camera, the image that camera gives alone; with
    small chunks too (later chunks skip stopped pixels of every camera)."""
    splat = random_splat(5, n=300, sh_degree=1)
    cams = [
        PinholeCamera.look_at(eye, (0, 0, 0), width=36, height=28, fovy_deg=fov)
        for eye, fov in (((0.3, -2.5, 1.0), 60), ((2.0, 1.0, 0.5), 45), ((-1.5, -1.5, 2.0), 70))
    ]
    for chunk in (rast.MAX_PAIRS_PER_CHUNK, 500):
        monkeypatch.setattr(rast, "MAX_PAIRS_PER_CHUNK", chunk)
        batch = rast.rasterize_torch(splat, cams, background=(0.1, 0.2, 0.3))
        assert batch.rgb.shape == (3, 28, 36, 3) and batch.alpha.shape == (3, 28, 36)
        for c, cam in enumerate(cams):
            alone = rast.rasterize_torch(splat, cam, background=(0.1, 0.2, 0.3))
            assert alone.alpha.mean() > 0.05  # the camera sees the splat
            torch.testing.assert_close(batch.rgb[c], alone.rgb, atol=1e-5, rtol=0)
            torch.testing.assert_close(batch.alpha[c], alone.alpha, atol=1e-5, rtol=0)
            torch.testing.assert_close(batch.depth[c], alone.depth, atol=1e-4, rtol=0)
    with pytest.raises(ValueError, match="share one image size"):
        rast.rasterize_torch(splat, [cams[0], PinholeCamera.look_at((1, 1, 1), (0, 0, 0))])


def test_stages_projection_pairs_and_compositing():
    """Each stage on one Gaussian seen head-on: projection puts it at the image centre with
    the screen variance of f * s / z; its pairs are exactly the pixels within its footprint
    ellipse; compositing one pair gives alpha = opacity * exp(-q / 2)."""
    scale, opacity, dist = 0.1, 0.8, 2.0
    cam = PinholeCamera.look_at((0, -dist, 0), (0, 0, 0), width=32, height=32, fovy_deg=60)
    splat = single((0, 0, 0), scale, opacity)
    cams = rast.CameraBatch.of([cam, cam], torch.device("cpu"), torch.float32)
    pr = rast.project(splat, cams)
    assert pr.cam.tolist() == [0, 1]  # one instance per camera
    var = (cam.fx * scale / dist) ** 2 + rast.LOW_PASS
    assert pr.mx.tolist() == pytest.approx([16.0, 16.0], abs=1e-4)
    assert pr.my.tolist() == pytest.approx([16.0, 16.0 + 32], abs=1e-4)  # stacked rows
    assert pr.sxx.tolist() == pytest.approx([var, var], rel=1e-4)
    assert pr.sxy.abs().max() < 1e-5
    v0, rows = rast.row_ranges(pr, 32)
    pix, gp, q = rast.expand_pairs(pr, torch.arange(2), v0, rows, 32)
    u, v = pix % 32, pix // 32
    assert set(gp.tolist()) == {0, 1} and bool(((v >= 32) == (gp == 1)).all())
    # q is the Mahalanobis distance of the pixel centre, all pairs lie within q_max ...
    expect_q = ((u + 0.5 - pr.mx[gp]) ** 2 + (v + 0.5 - pr.my[gp]) ** 2) / var
    torch.testing.assert_close(q, expect_q.to(q.dtype), rtol=1e-4, atol=1e-4)
    assert bool((q <= pr.q_max[gp] + 1e-4).all())
    # ... and every pixel within q_max is a pair (for camera 0)
    uu, vv = torch.meshgrid(torch.arange(32), torch.arange(32), indexing="xy")
    within = ((uu + 0.5 - 16) ** 2 + (vv + 0.5 - 16) ** 2) / var <= float(pr.q_max[0]) - 1e-3
    assert set((vv * 32 + uu)[within].tolist()) <= set(pix[gp == 0].tolist())
    canvas = rast.Canvas.empty(32 * 64, torch.device("cpu"))
    centre = (v == 16) & (u == 16) & (gp == 0)
    rast.composite_pairs(canvas, pr, pix[centre], gp[centre], q[centre])
    alpha = 1 - math.exp(float(canvas.log_t[16 * 32 + 16]))
    assert alpha == pytest.approx(opacity * math.exp(-0.5 * float(q[centre][0])), rel=1e-5)


def test_sh_colours_of_many_cameras_in_one_call():
    splat = random_splat(1, n=50, sh_degree=2)
    centres = torch.tensor([[1.0, 2.0, 3.0], [-1.0, 0.5, 2.0]])
    batch = sh_colors(splat, centres[:, None, :])
    assert batch.shape == (2, 50, 3)
    for k in range(2):
        torch.testing.assert_close(batch[k], sh_colors(splat, centres[k]))
    assert not torch.allclose(batch[0], batch[1])  # view-dependent: the cameras differ
