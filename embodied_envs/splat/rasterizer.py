"""EWA splatting of 3D Gaussians in PyTorch (CPU or CUDA).

The rules (as in 3DGS): Gaussians with camera z <= ``NEAR_Z`` are dropped and centres outside
``FRUSTUM_MARGIN`` times the view frustum are culled (so the perspective Jacobian is only
evaluated within that margin, where 3DGS clamps it); the 3D covariance is projected with that
Jacobian plus a ``LOW_PASS`` px^2 filter; a Gaussian covers the pixels whose centres lie within
its ``FOOTPRINT_SIGMA``-sigma ellipse; per pixel, Gaussians are composited front to back by
camera z with ``alpha = min(ALPHA_MAX, opacity * exp(-q / 2))``, skipping ``alpha <
ALPHA_MIN``, and a pixel stops at the first Gaussian that would take its transmittance below
``T_MIN``.

Stages, each a function that can be tested on its own (as gsplat splits its rasterizer):

1. :func:`project`: cull, project and colour the Gaussians of every camera, sorted by depth;
2. :func:`expand_pairs`: the (pixel, Gaussian) pairs of each footprint, row by row;
3. :func:`composite_pairs`: per pixel, a segmented cumulative sum of ``log(1 - alpha)`` gives
   each pair's transmittance, which reproduces sequential compositing exactly, stop rule
   included.

:func:`rasterize_torch` runs them over depth-sorted chunks of Gaussians; pixels that have
stopped are skipped by later chunks. Several cameras of one size render in one call: their
images are stacked into one tall image (camera ``c`` owns rows ``c*H .. c*H+H-1``), so every
stage works on all cameras at once.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from embodied_envs.splat.camera import PinholeCamera
from embodied_envs.splat.model import GaussianSplat, quat_wxyz_to_matrix, sh_colors

NEAR_Z = 0.01  # m, Gaussians nearer than this (camera z) are dropped
FRUSTUM_MARGIN = 1.3  # centres beyond this multiple of the half field of view are culled
LOW_PASS = 0.3  # px^2 added to the 2D covariance's diagonal (anti-aliasing)
FOOTPRINT_SIGMA = 3.0  # a Gaussian covers pixels within this many sigmas (Mahalanobis)
ALPHA_MAX = 0.99  # per-Gaussian alpha clamp
ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped
T_MIN = 1e-4  # a pixel stops before its transmittance would drop below this
MAX_PAIRS_PER_CHUNK = 1 << 19  # pairs expanded at once; smaller chunks skip more hidden pairs
# on CUDA each chunk's host syncs cost more than the hidden pairs a small chunk skips: 2^24 pairs
# rendered 16 views of the shipped room 3.2x faster than 2^19 on an H100 (docs/benchmarks.md)
MAX_PAIRS_PER_CHUNK_CUDA = 1 << 24


@dataclass(frozen=True)
class SplatImage:
    """A rendered splat; with several cameras every field has a leading camera dimension.

    Attributes:
        rgb: ([C,] H, W, 3) float in [0, 1], composited over the background colour.
        alpha: ([C,] H, W) accumulated opacity, 1 - final transmittance.
        depth: ([C,] H, W) sum over contributions of weight x camera z (not divided by alpha).
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor

    def surface_depth(self, min_alpha: float = 0.5) -> torch.Tensor:
        """Expected depth of the splat surface, depth / alpha; +inf where alpha < min_alpha."""
        d = self.depth / self.alpha.clamp_min(1e-12)
        return torch.where(self.alpha >= min_alpha, d, torch.full_like(d, math.inf))

    def rgb_uint8(self) -> torch.Tensor:
        return (self.rgb * 255.0 + 0.5).clamp(0, 255).to(torch.uint8)


@dataclass(frozen=True)
class CameraBatch:
    """Cameras of one image size as tensors: the rasterizer's batched camera argument."""

    world_to_cam: torch.Tensor  # (C, 4, 4)
    fx: torch.Tensor  # (C,) each
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    center: torch.Tensor  # (C, 3) camera centres in world coordinates
    width: int
    height: int

    @classmethod
    def of(
        cls, cameras: Sequence[PinholeCamera], device: torch.device, dtype: torch.dtype
    ) -> CameraBatch:
        """Stack pinhole cameras.

        Raises:
            ValueError: no camera, or cameras of different image sizes.
        """
        if not cameras:
            raise ValueError("render needs at least one camera")
        sizes = {(c.width, c.height) for c in cameras}
        if len(sizes) > 1:
            raise ValueError(f"cameras rendered in one call share one image size, got {sizes}")

        def t(values) -> torch.Tensor:
            return torch.as_tensor(np.asarray(values), dtype=dtype, device=device)

        return cls(
            world_to_cam=t([c.world_to_cam for c in cameras]),
            fx=t([c.fx for c in cameras]),
            fy=t([c.fy for c in cameras]),
            cx=t([c.cx for c in cameras]),
            cy=t([c.cy for c in cameras]),
            center=t([c.center for c in cameras]),
            width=cameras[0].width,
            height=cameras[0].height,
        )

    def __len__(self) -> int:
        return self.world_to_cam.shape[0]


@dataclass(frozen=True)
class Projected:
    """Visible (camera, Gaussian) instances in screen space, sorted front to back (all (M,)).

    Rows are in the stacked image of all cameras: camera ``c`` owns rows ``c*H .. c*H+H-1``.
    """

    cam: torch.Tensor  # camera index
    mx: torch.Tensor  # pixel coordinates of the centre (my in the stacked image)
    my: torch.Tensor
    sxx: torch.Tensor  # 2D covariance, px^2, low-pass included
    sxy: torch.Tensor
    syy: torch.Tensor
    depth: torch.Tensor  # camera z
    opacity: torch.Tensor
    log_opacity: torch.Tensor  # log(opacity), once per instance rather than per pair
    color: torch.Tensor  # (M, 3)

    @property
    def q_max(self) -> torch.Tensor:
        """Largest Mahalanobis q a Gaussian contributes at (footprint, alpha >= ALPHA_MIN)."""
        return (2.0 * torch.log(self.opacity / ALPHA_MIN)).clamp_max(FOOTPRINT_SIGMA**2)


def project(splat: GaussianSplat, cameras: CameraBatch) -> Projected:
    """Stage 1: cull, project and colour every Gaussian in every camera, sorted by camera z
    (ties keep camera, then Gaussian order)."""
    c, n = len(cameras), len(splat)
    rot, trans = cameras.world_to_cam[:, :3, :3], cameras.world_to_cam[:, :3, 3]
    p = torch.matmul(splat.means, rot.transpose(1, 2)) + trans[:, None]  # (C, N, 3)
    z = p[..., 2]
    w, h = cameras.width, cameras.height
    lim_x = FRUSTUM_MARGIN * torch.maximum(cameras.cx, w - cameras.cx) / cameras.fx
    lim_y = FRUSTUM_MARGIN * torch.maximum(cameras.cy, h - cameras.cy) / cameras.fy
    keep = (
        (z > NEAR_Z)
        & (p[..., 0].abs() <= lim_x[:, None] * z)
        & (p[..., 1].abs() <= lim_y[:, None] * z)
    )
    flat = keep.view(-1).nonzero().squeeze(1)  # camera * N + Gaussian, camera-major
    p = p.view(-1, 3)
    flat = flat.index_select(0, torch.argsort(p[:, 2].index_select(0, flat), stable=True))
    cam, idx = flat // n, flat % n
    p = p.index_select(0, flat)
    z = p[:, 2]
    tx, ty = p[:, 0] / z, p[:, 1] / z  # within the culling margin: no Jacobian clamp needed
    q = splat.quats_wxyz.index_select(0, idx)
    rs = quat_wxyz_to_matrix(q / q.norm(dim=1, keepdim=True).clamp_min(1e-12))
    rs = rs * torch.exp(splat.log_scales.index_select(0, idx))[:, None, :]

    # per instance, its camera's rotation rows and intrinsics, in one gather
    per_cam = torch.cat(
        [rot.reshape(c, 9), torch.stack([cameras.fx, cameras.fy, cameras.cx, cameras.cy], 1)], 1
    ).index_select(0, cam)
    r0, r1, r2 = per_cam[:, 0:3], per_cam[:, 3:6], per_cam[:, 6:9]
    fx, fy, cx, cy = per_cam[:, 9:13].unbind(1)
    # 2D covariance: J R S (J R S)^T + LOW_PASS I, with J the perspective Jacobian; the rows of
    # J R S are (W_0 - tx W_2) R S fx / z and (W_1 - ty W_2) R S fy / z (W: camera rotation)
    ax = torch.bmm(((r0 - tx[:, None] * r2) * (fx / z)[:, None])[:, None], rs)[:, 0]
    ay = torch.bmm(((r1 - ty[:, None] * r2) * (fy / z)[:, None])[:, None], rs)[:, 0]
    opacity = torch.sigmoid(splat.opacity_logits.index_select(0, idx))
    # view-dependent colour needs each instance's camera centre; degree 0 needs none
    centre = cameras.center.index_select(0, cam) if splat.sh_degree > 0 else cameras.center[0]
    return Projected(
        cam=cam,
        mx=fx * tx + cx,
        my=fy * ty + cy + cam * h,
        sxx=(ax * ax).sum(1) + LOW_PASS,
        sxy=(ax * ay).sum(1),
        syy=(ay * ay).sum(1) + LOW_PASS,
        depth=z,
        opacity=opacity,
        log_opacity=torch.log(opacity),
        color=sh_colors(splat, centre, idx),
    )


def row_ranges(pr: Projected, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per instance: first row (stacked image) its footprint may cover, and the number of rows,
    within its own camera's rows."""
    half = torch.sqrt(pr.q_max.clamp_min(0.0) * pr.syy)
    top = pr.cam * height
    v0 = torch.maximum(torch.minimum(torch.ceil(pr.my - half - 0.5).long(), top + height), top)
    v1 = torch.minimum(
        torch.maximum(torch.floor(pr.my + half - 0.5).long(), top - 1), top + height - 1
    )
    return v0, (v1 - v0 + 1).clamp_min(0)


def expand_pairs(
    pr: Projected, g: torch.Tensor, v0: torch.Tensor, rows: torch.Tensor, width: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Stage 2: the (pixel, Gaussian) pairs of instances ``g``, instance-major, row by row.

    Each row of a footprint spans the exact pixel interval of the ellipse q <= q_max at that
    row: q = dy^2 / syy + (dx - dy sxy / syy)^2 / (sxx - sxy^2 / syy).

    Returns:
        pixel index (in the stacked image), instance index and q of every pair.
    """
    dev = g.device
    n_rows = int(rows.sum())
    row_g = torch.repeat_interleave(g, rows, output_size=n_rows)
    first_row = torch.repeat_interleave(rows.cumsum(0) - rows, rows, output_size=n_rows)
    v = v0.index_select(0, row_g) + (torch.arange(n_rows, device=dev) - first_row)
    syy = pr.syy.index_select(0, row_g)
    sxy = pr.sxy.index_select(0, row_g)
    dy = v.float() + 0.5 - pr.my.index_select(0, row_g)
    q_row = dy * dy / syy
    cond = pr.sxx.index_select(0, row_g) - sxy * sxy / syy  # conditional variance of dx
    center = pr.mx.index_select(0, row_g) + dy * sxy / syy
    half = torch.sqrt((pr.q_max.index_select(0, row_g) - q_row).clamp_min(0.0) * cond)
    u0 = torch.ceil(center - half - 0.5).clamp(0, width).long()
    u1 = torch.floor(center + half - 0.5).clamp(-1, width - 1).long()
    span = (u1 - u0 + 1).clamp_min(0)
    n_pairs = int(span.sum())
    pair_row = torch.repeat_interleave(torch.arange(n_rows, device=dev), span, output_size=n_pairs)
    first_px = (span.cumsum(0) - span - v * width - u0).index_select(0, pair_row)
    pixel = torch.arange(n_pairs, device=dev) - first_px  # = v * width + u
    dx = (
        (pixel - v.index_select(0, pair_row) * width).float()
        + 0.5
        - center.index_select(0, pair_row)
    )
    q = q_row.index_select(0, pair_row) + dx * dx / cond.index_select(0, pair_row)
    return pixel, row_g.index_select(0, pair_row), q


def _live_counts(done: torch.Tensor, width: int, height: int, u0, v0, bw, bh) -> torch.Tensor:
    """Number of not-yet-stopped pixels inside each box (summed-area table)."""
    live = (~done).view(height, width).to(torch.int32)
    sat = torch.zeros((height + 1, width + 1), dtype=torch.int32, device=done.device)
    sat[1:, 1:] = live.cumsum(0).cumsum(1)
    u1, v1 = u0 + bw, v0 + bh
    return sat[v1, u1] - sat[v0, u1] - sat[v1, u0] + sat[v0, u0]


@dataclass
class Canvas:
    """Per-pixel accumulators of the stacked image: colour, depth, log transmittance, stopped."""

    color: torch.Tensor  # (P, 3) float32
    depth: torch.Tensor  # (P,) float32
    log_t: torch.Tensor  # (P,) float64
    done: torch.Tensor  # (P,) bool

    @classmethod
    def empty(cls, pixels: int, device: torch.device) -> Canvas:
        return cls(
            color=torch.zeros((pixels, 3), dtype=torch.float32, device=device),
            depth=torch.zeros(pixels, dtype=torch.float32, device=device),
            log_t=torch.zeros(pixels, dtype=torch.float64, device=device),
            done=torch.zeros(pixels, dtype=torch.bool, device=device),
        )


def composite_pairs(
    canvas: Canvas, pr: Projected, pix: torch.Tensor, gp: torch.Tensor, q: torch.Tensor
) -> None:
    """Stage 3: composite pairs onto ``canvas`` (in place). Pairs come in depth order per
    pixel (instance-major, instances sorted by depth)."""
    # pairs outside the footprint, below ALPHA_MIN or on stopped pixels become alpha = 0:
    # they neither contribute nor change transmittance, so no compaction is needed
    alpha = torch.exp(pr.log_opacity.index_select(0, gp) - 0.5 * q).clamp_max(ALPHA_MAX)
    ok = (q <= FOOTPRINT_SIGMA**2) & (alpha >= ALPHA_MIN) & ~canvas.done.index_select(0, pix)
    alpha = alpha * ok
    pix, order = torch.sort(pix.int(), stable=True)  # int32 sorts faster
    pix = pix.long()
    gp, alpha = gp.index_select(0, order), alpha.index_select(0, order)

    # per-pixel prefix sums of log(1 - alpha) in depth order; the running sum is
    # non-increasing, so a cummin over segment starts recovers each segment's base
    logs = torch.log1p(-alpha.double())
    csum = logs.cumsum(0)
    excl = csum - logs
    first = torch.ones_like(pix, dtype=torch.bool)
    first[1:] = pix[1:] != pix[:-1]
    base = torch.cummin(torch.where(first, excl, math.inf), 0).values
    before_t = canvas.log_t.index_select(0, pix) + (excl - base)
    include = before_t + logs >= math.log(T_MIN)
    weight = (alpha * torch.exp(before_t).float()) * include
    canvas.color.index_add_(0, pix, weight[:, None] * pr.color.index_select(0, gp))
    canvas.depth.index_add_(0, pix, weight * pr.depth.index_select(0, gp))
    canvas.log_t.index_add_(0, pix, logs * include)
    canvas.done[pix[~include]] = True


def rasterize_torch(
    splat: GaussianSplat,
    camera: PinholeCamera | Sequence[PinholeCamera],
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> SplatImage:
    """Render a splat with the PyTorch rasterizer, on the splat's device (CPU or CUDA).

    Args:
        camera: one camera, or a sequence of cameras of one image size rendered in one call
            (the image then has a leading camera dimension).
    """
    dev = splat.device
    cameras = CameraBatch.of(
        [camera] if isinstance(camera, PinholeCamera) else list(camera), dev, splat.means.dtype
    )
    w, h = cameras.width, len(cameras) * cameras.height  # the stacked image
    pr = project(splat, cameras)
    v0, rows = row_ranges(pr, cameras.height)
    half_x = torch.sqrt(pr.q_max.clamp_min(0.0) * pr.sxx)
    bound = rows * (2 * half_x.ceil().long() + 1).clamp_max(w)  # pairs per instance, at most
    canvas = Canvas.empty(w * h, dev)

    cum = bound.cumsum(0)
    chunk = MAX_PAIRS_PER_CHUNK_CUDA if dev.type == "cuda" else MAX_PAIRS_PER_CHUNK
    n = len(bound)
    start = 0
    while start < n:
        before = int(cum[start - 1]) if start else 0
        end = int(torch.searchsorted(cum, before + chunk, right=True))
        end = max(end, start + 1)
        g = torch.arange(start, end, device=dev)
        start = end
        r = rows.index_select(0, g)
        if before > 0 and bool(canvas.done.any()):
            # later chunks: skip instances whose box holds only stopped pixels
            hx = half_x.index_select(0, g)
            mx = pr.mx.index_select(0, g)
            u0 = torch.ceil(mx - hx - 0.5).clamp(0, w).long()
            u1 = torch.floor(mx + hx - 0.5).clamp(-1, w - 1).long()
            live = _live_counts(
                canvas.done, w, h, u0, v0.index_select(0, g), (u1 - u0 + 1).clamp_min(0), r
            )
            r = torch.where(live > 0, r, torch.zeros_like(r))
        if int(r.sum()) == 0:
            continue
        pix, gp, q = expand_pairs(pr, g, v0, r, w)
        if len(pix):
            composite_pairs(canvas, pr, pix, gp, q)

    trans = torch.exp(canvas.log_t).float()
    bg = torch.as_tensor(background, dtype=torch.float32, device=dev)
    shape = (cameras.height, w)
    if not isinstance(camera, PinholeCamera):
        shape = (len(cameras), *shape)
    return SplatImage(
        rgb=(canvas.color + trans[:, None] * bg).view(*shape, 3).clamp(0.0, 1.0),
        alpha=(1.0 - trans).view(shape),
        depth=canvas.depth.view(shape),
    )
