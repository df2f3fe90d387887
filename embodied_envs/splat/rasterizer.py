"""EWA splatting of 3D Gaussians in PyTorch (CPU or CUDA), and the backend switch.

The rules (as in 3DGS): Gaussians with camera z <= ``NEAR_Z`` are dropped and
centres outside ``FRUSTUM_MARGIN`` times the view frustum are culled; the 3D covariance is
projected with the perspective Jacobian (x/z and y/z clamped to the same margin) plus a
``LOW_PASS`` px^2 filter; a Gaussian covers the pixels whose centres lie within its
``FOOTPRINT_SIGMA``-sigma ellipse; per pixel, Gaussians are composited front to back by camera
z with ``alpha = min(ALPHA_MAX, opacity * exp(-q / 2))``, skipping ``alpha < ALPHA_MIN``, and
a pixel stops at the first Gaussian that would take its transmittance below ``T_MIN``.

Implementation: every Gaussian is expanded into the (pixel, Gaussian) pairs of its footprint,
in depth-sorted chunks; per pixel, a segmented cumulative sum of ``log(1 - alpha)`` gives each
pair's transmittance, which reproduces sequential compositing exactly, stop rule included.
Pixels that have stopped are skipped by later chunks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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


@dataclass(frozen=True)
class SplatImage:
    """A rendered splat.

    Attributes:
        rgb: (H, W, 3) float in [0, 1], composited over the background colour.
        alpha: (H, W) accumulated opacity, 1 - final transmittance.
        depth: (H, W) sum over contributions of weight x camera z (not divided by alpha).
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
class Projected:
    """Visible Gaussians in screen space, sorted front to back (all tensors (M,))."""

    mx: torch.Tensor  # pixel coordinates of the centre
    my: torch.Tensor
    sxx: torch.Tensor  # 2D covariance, px^2, low-pass included
    sxy: torch.Tensor
    syy: torch.Tensor
    depth: torch.Tensor  # camera z
    opacity: torch.Tensor
    color: torch.Tensor  # (M, 3)

    @property
    def q_max(self) -> torch.Tensor:
        """Largest Mahalanobis q a Gaussian contributes at (footprint, alpha >= ALPHA_MIN)."""
        return (2.0 * torch.log(self.opacity / ALPHA_MIN)).clamp_max(FOOTPRINT_SIGMA**2)


def project(splat: GaussianSplat, camera: PinholeCamera) -> Projected:
    """Cull, project and colour the Gaussians; the result is sorted by camera z."""
    dev, dt = splat.device, splat.means.dtype
    w2c = torch.as_tensor(camera.world_to_cam, dtype=dt, device=dev)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    p = torch.addmm(trans, splat.means, rot.T)
    z = p[:, 2]
    lim_x = FRUSTUM_MARGIN * max(camera.cx, camera.width - camera.cx) / camera.fx
    lim_y = FRUSTUM_MARGIN * max(camera.cy, camera.height - camera.cy) / camera.fy
    keep = (z > NEAR_Z) & (p[:, 0].abs() <= lim_x * z) & (p[:, 1].abs() <= lim_y * z)
    idx = keep.nonzero().squeeze(1)
    idx = idx.index_select(0, torch.argsort(z.index_select(0, idx), stable=True))
    p = p.index_select(0, idx)
    z = p[:, 2]
    tx, ty = p[:, 0] / z, p[:, 1] / z
    q = splat.quats_wxyz.index_select(0, idx)
    rs = quat_wxyz_to_matrix(q / q.norm(dim=1, keepdim=True).clamp_min(1e-12))
    rs = rs * torch.exp(splat.log_scales.index_select(0, idx))[:, None, :]
    m = torch.matmul(rot, rs)  # R S in the camera frame

    # 2D covariance: J R S (J R S)^T + LOW_PASS I, with J the clamped perspective Jacobian
    txc, tyc = tx.clamp(-lim_x, lim_x), ty.clamp(-lim_y, lim_y)
    ax = (m[:, 0] - txc[:, None] * m[:, 2]) * (camera.fx / z)[:, None]
    ay = (m[:, 1] - tyc[:, None] * m[:, 2]) * (camera.fy / z)[:, None]
    center = torch.as_tensor(camera.center, dtype=dt, device=dev)
    return Projected(
        mx=camera.fx * tx + camera.cx,
        my=camera.fy * ty + camera.cy,
        sxx=(ax * ax).sum(1) + LOW_PASS,
        sxy=(ax * ay).sum(1),
        syy=(ay * ay).sum(1) + LOW_PASS,
        depth=z,
        opacity=torch.sigmoid(splat.opacity_logits.index_select(0, idx)),
        color=sh_colors(splat, center, idx),
    )


def _row_ranges(pr: Projected, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per Gaussian: first pixel row its footprint may cover, and the number of rows."""
    half = torch.sqrt(pr.q_max.clamp_min(0.0) * pr.syy)
    v0 = torch.ceil(pr.my - half - 0.5).clamp(0, height).long()
    v1 = torch.floor(pr.my + half - 0.5).clamp(-1, height - 1).long()
    return v0, (v1 - v0 + 1).clamp_min(0)


def _expand(pr: Projected, g: torch.Tensor, v0: torch.Tensor, rows: torch.Tensor, width: int):
    """The (pixel, Gaussian) pairs of Gaussians ``g``, Gaussian-major, row by row.

    Each row of a footprint spans the exact pixel interval of the ellipse q <= q_max at that
    row: q = dy^2 / syy + (dx - dy sxy / syy)^2 / (sxx - sxy^2 / syy).

    Returns:
        pixel index, Gaussian index and q of every pair.
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


def rasterize_torch(
    splat: GaussianSplat,
    camera: PinholeCamera,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> SplatImage:
    """Render a splat with the PyTorch rasterizer, on the splat's device (CPU or CUDA)."""
    dev = splat.device
    w, h = camera.width, camera.height
    pr = project(splat, camera)
    v0, rows = _row_ranges(pr, h)
    half_x = torch.sqrt(pr.q_max.clamp_min(0.0) * pr.sxx)
    bound = rows * (2 * half_x.ceil().long() + 1).clamp_max(w)  # pairs per Gaussian, at most

    npix = w * h
    color = torch.zeros((npix, 3), dtype=torch.float32, device=dev)
    depth = torch.zeros(npix, dtype=torch.float32, device=dev)
    log_t = torch.zeros(npix, dtype=torch.float64, device=dev)
    done = torch.zeros(npix, dtype=torch.bool, device=dev)
    log_t_min = math.log(T_MIN)
    log_opacity = torch.log(pr.opacity)

    cum = bound.cumsum(0)
    n = len(bound)
    start = 0
    while start < n:
        before = int(cum[start - 1]) if start else 0
        end = int(torch.searchsorted(cum, before + MAX_PAIRS_PER_CHUNK, right=True))
        end = max(end, start + 1)
        g = torch.arange(start, end, device=dev)
        start = end
        r = rows.index_select(0, g)
        if before > 0 and bool(done.any()):
            # later chunks: skip Gaussians whose box holds only stopped pixels
            hx = half_x.index_select(0, g)
            mx = pr.mx.index_select(0, g)
            u0 = torch.ceil(mx - hx - 0.5).clamp(0, w).long()
            u1 = torch.floor(mx + hx - 0.5).clamp(-1, w - 1).long()
            live = _live_counts(
                done, w, h, u0, v0.index_select(0, g), (u1 - u0 + 1).clamp_min(0), r
            )
            r = torch.where(live > 0, r, torch.zeros_like(r))
        if int(r.sum()) == 0:
            continue
        pix, gp, q = _expand(pr, g, v0, r, w)
        if len(pix) == 0:
            continue
        # pairs outside the footprint, below ALPHA_MIN or on stopped pixels become alpha = 0:
        # they neither contribute nor change transmittance, so no compaction is needed
        alpha = torch.exp(log_opacity.index_select(0, gp) - 0.5 * q).clamp_max(ALPHA_MAX)
        ok = (q <= FOOTPRINT_SIGMA**2) & (alpha >= ALPHA_MIN) & ~done.index_select(0, pix)
        alpha = alpha * ok
        pix, order = torch.sort(pix.int(), stable=True)
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
        before_t = log_t.index_select(0, pix) + (excl - base)
        include = before_t + logs >= log_t_min
        weight = (alpha * torch.exp(before_t).float()) * include
        color.index_add_(0, pix, weight[:, None] * pr.color.index_select(0, gp))
        depth.index_add_(0, pix, weight * pr.depth.index_select(0, gp))
        log_t.index_add_(0, pix, logs * include)
        done[pix[~include]] = True

    trans = torch.exp(log_t).float()
    bg = torch.as_tensor(background, dtype=torch.float32, device=dev)
    rgb = color + trans[:, None] * bg
    return SplatImage(
        rgb=rgb.view(h, w, 3).clamp(0.0, 1.0),
        alpha=(1.0 - trans).view(h, w),
        depth=depth.view(h, w),
    )
