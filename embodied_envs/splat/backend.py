"""One entry point for rendering a splat, whichever backend draws it.

Backends: ``"torch"`` (:func:`rasterize_torch`, CPU or CUDA, always available) and ``"gsplat"``
(CUDA only, when the ``gsplat`` package is installed). ``"auto"`` picks gsplat when it can run,
else torch. Both take the same inputs and return a :class:`SplatImage` with the same meaning.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence

import torch

from embodied_envs.splat import BACKENDS
from embodied_envs.splat.camera import PinholeCamera
from embodied_envs.splat.model import GaussianSplat, sh_colors
from embodied_envs.splat.rasterizer import (
    LOW_PASS,
    NEAR_Z,
    CameraBatch,
    SplatImage,
    rasterize_torch,
)


def gsplat_available() -> bool:
    """True when gsplat is installed and a CUDA device is present."""
    return importlib.util.find_spec("gsplat") is not None and torch.cuda.is_available()


def resolve_backend(backend: str) -> str:
    """The concrete backend for a request; raises ValueError naming the fix when it can't run."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown splat backend {backend!r}; use one of {list(BACKENDS)}")
    if backend == "auto":
        return "gsplat" if gsplat_available() else "torch"
    if backend == "gsplat" and not gsplat_available():
        why = "no CUDA device" if importlib.util.find_spec("gsplat") else "gsplat not installed"
        raise ValueError(
            f'splat backend "gsplat" cannot run here ({why}); install it with '
            '`pip install -e .[gsplat]` on a CUDA machine, or use backend "torch"'
        )
    return backend


def _rasterize_gsplat(
    splat: GaussianSplat, cameras: CameraBatch, background: tuple[float, float, float]
) -> SplatImage:
    """All cameras in one gsplat call; returns ``(C, H, W, ...)`` images."""
    from gsplat import rasterization  # an optional dependency (the gsplat extra)

    dev, c = splat.device, len(cameras)
    k = torch.zeros((c, 3, 3), dtype=torch.float32, device=dev)
    k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2] = (
        cameras.fx,
        cameras.fy,
        cameras.cx,
        cameras.cy,
    )
    k[:, 2, 2] = 1.0
    # colours are evaluated here, per camera, so posed splats (sh_frame) get the same SH colour
    colors = sh_colors(splat, cameras.center[:, None, :])
    colors, alphas, _ = rasterization(
        means=splat.means,
        quats=splat.unit_quats_wxyz,
        scales=splat.scales,
        opacities=splat.opacities,
        colors=colors.expand(c, -1, -1) if colors.dim() == 2 else colors,
        viewmats=cameras.world_to_cam.float(),
        Ks=k,
        width=cameras.width,
        height=cameras.height,
        near_plane=NEAR_Z,
        eps2d=LOW_PASS,
        backgrounds=torch.as_tensor(background, dtype=torch.float32, device=dev).expand(c, 3),
        render_mode="RGB+D",
        packed=False,
    )
    return SplatImage(
        rgb=colors[..., :3].clamp(0.0, 1.0), alpha=alphas[..., 0], depth=colors[..., 3]
    )


def render(
    splat: GaussianSplat,
    camera: PinholeCamera | Sequence[PinholeCamera],
    backend: str = "auto",
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> SplatImage:
    """Render ``splat`` (on its own device) from ``camera``.

    Args:
        splat: the Gaussians, already posed in the camera's world frame.
        camera: an OpenCV-style pinhole camera, or a sequence of cameras of one image size,
            rendered in one call (every image field then has a leading camera dimension).
        backend: ``"auto"``, ``"torch"`` or ``"gsplat"``.
        background: RGB in [0, 1] behind the splat.

    Raises:
        ValueError: the backend is unknown or cannot run on this machine, or the cameras
            differ in image size.
    """
    chosen = resolve_backend(backend)
    if chosen == "torch":
        return rasterize_torch(splat, camera, background)
    if splat.device.type != "cuda":
        splat = splat.to("cuda")
    single = isinstance(camera, PinholeCamera)
    cameras = CameraBatch.of([camera] if single else list(camera), splat.device, torch.float32)
    image = _rasterize_gsplat(splat, cameras, background)
    if single:
        return SplatImage(rgb=image.rgb[0], alpha=image.alpha[0], depth=image.depth[0])
    return image
