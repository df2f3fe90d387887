"""The Gaussian-splat model: raw (pre-activation) parameters as 3DGS stores them."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from embodied_envs.splat.sh import MAX_SH_DEGREE, SH_C0, sh_coeff_count


@dataclass(frozen=True)
class GaussianSplat:
    """A set of 3D Gaussians with the raw parameters of the INRIA 3DGS PLY layout.

    Values are kept as stored (log-scales, opacity logits, unnormalised ``w x y z``
    quaternions) so that reading and writing a file is lossless; the activated values come
    from the properties.

    Attributes:
        means: (N, 3) centres.
        quats_wxyz: (N, 4) orientations, scalar first, not necessarily normalised.
        log_scales: (N, 3) per-axis standard deviations before ``exp``.
        opacity_logits: (N,) opacities before ``sigmoid``.
        sh: (N, K, 3) spherical-harmonic coefficients, K = (degree + 1)^2; ``sh[:, 0]`` is
            ``f_dc``.
        normals: (N, 3) or None; carried through reading and writing, unused for rendering.
        sh_frame: (3, 3) rotation from the splat's own frame to the frame its means live in;
            view directions are rotated back by it before evaluating the SH colour.
    """

    means: torch.Tensor
    quats_wxyz: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    sh: torch.Tensor
    normals: torch.Tensor | None = None
    sh_frame: torch.Tensor | None = None

    def __post_init__(self):
        n = self.means.shape[0]
        shapes = {
            "means": (self.means, (n, 3)),
            "quats_wxyz": (self.quats_wxyz, (n, 4)),
            "log_scales": (self.log_scales, (n, 3)),
            "opacity_logits": (self.opacity_logits, (n,)),
        }
        if self.normals is not None:
            shapes["normals"] = (self.normals, (n, 3))
        for name, (t, shape) in shapes.items():
            if tuple(t.shape) != shape:
                raise ValueError(f"GaussianSplat.{name} has shape {tuple(t.shape)}, want {shape}")
        k = self.sh.shape[1] if self.sh.ndim == 3 else -1
        if (
            self.sh.ndim != 3
            or self.sh.shape[0] != n
            or self.sh.shape[2] != 3
            or k not in (sh_coeff_count(d) for d in range(MAX_SH_DEGREE + 1))
        ):
            raise ValueError(
                f"GaussianSplat.sh has shape {tuple(self.sh.shape)}, want ({n}, (d+1)^2, 3) "
                f"with degree d in 0..{MAX_SH_DEGREE}"
            )

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return round(self.sh.shape[1] ** 0.5) - 1

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.opacity_logits)

    @property
    def scales(self) -> torch.Tensor:
        return torch.exp(self.log_scales)

    @property
    def unit_quats_wxyz(self) -> torch.Tensor:
        return self.quats_wxyz / self.quats_wxyz.norm(dim=1, keepdim=True).clamp_min(1e-12)

    def to(self, device: torch.device | str) -> GaussianSplat:
        def move(t):
            return None if t is None else t.to(device)

        return replace(
            self,
            **{
                f: move(getattr(self, f))
                for f in (
                    "means",
                    "quats_wxyz",
                    "log_scales",
                    "opacity_logits",
                    "sh",
                    "normals",
                    "sh_frame",
                )
            },
        )


def quat_wxyz_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(N, 4) unit quaternions (scalar first) to (N, 3, 3) rotation matrices."""
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*q.shape[:-1], 3, 3)


def quat_wxyz_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b`` (rotate by b, then by a), scalar-first, broadcasting."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def pose_splat(
    splat: GaussianSplat, position: torch.Tensor, quat_wxyz: torch.Tensor
) -> GaussianSplat:
    """The splat moved by a rigid pose: means ``R x + t``, orientations ``q_pose * q``.

    The pose's rotation is also folded into ``sh_frame`` so that view-dependent colour is
    evaluated with view directions rotated back into the splat's own frame.

    Args:
        splat: the splat in its own frame.
        position: (3,) translation.
        quat_wxyz: (4,) rotation, scalar first (normalised here).
    """
    dev, dt = splat.means.device, splat.means.dtype
    q = torch.as_tensor(quat_wxyz, dtype=dt, device=dev)
    q = q / q.norm()
    t = torch.as_tensor(position, dtype=dt, device=dev)
    rot = quat_wxyz_to_matrix(q[None])[0]
    frame = rot if splat.sh_frame is None else rot @ splat.sh_frame.to(dev, dt)
    return replace(
        splat,
        means=splat.means @ rot.T + t,
        quats_wxyz=quat_wxyz_multiply(q[None], splat.quats_wxyz),
        normals=None if splat.normals is None else splat.normals @ rot.T,
        sh_frame=frame,
    )


# Real spherical-harmonic constants of degrees 1..3, in the order 3DGS uses.
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """(N, 3) unit directions to the (N, (degree+1)^2) real SH basis, 3DGS sign convention."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [
            SH_C2[0] * xy,
            SH_C2[1] * yz,
            SH_C2[2] * (2 * zz - xx - yy),
            SH_C2[3] * xz,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, dim=-1)


def sh_colors(
    splat: GaussianSplat, camera_center: torch.Tensor, index: torch.Tensor | None = None
) -> torch.Tensor:
    """RGB in [0, 1] of each Gaussian (or of ``index``) seen from ``camera_center``.

    Colour = 0.5 + sum_k basis_k(view direction) * sh_k, clamped to [0, 1], with the view
    direction (camera to Gaussian) rotated into the splat's own frame. ``camera_center`` is
    ``(3,)``, one centre per Gaussian ``(M, 3)``, or ``(C, 1, 3)`` for ``(C, N, 3)`` colours of
    C cameras (degree 0 gives ``(N, 3)``, the same from every camera).
    """
    means = splat.means if index is None else splat.means[index]
    sh = splat.sh if index is None else splat.sh[index]
    if splat.sh_degree == 0:
        return (0.5 + SH_C0 * sh[:, 0]).clamp(0.0, 1.0)
    dirs = means - camera_center
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if splat.sh_frame is not None:
        dirs = dirs @ splat.sh_frame.to(dirs)  # row vectors: R^T d for each d
    basis = sh_basis(dirs, splat.sh_degree)
    return (0.5 + torch.einsum("...k,...kc->...c", basis, sh)).clamp(0.0, 1.0)
