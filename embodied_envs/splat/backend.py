"""One entry point for rendering a splat, whichever backend draws it.

Backends: ``"torch"`` (:func:`rasterize_torch`, CPU or CUDA, always available) and ``"gsplat"``
(CUDA only, when the ``gsplat`` package is installed). ``"auto"`` picks gsplat when it can run,
else torch. Both take the same inputs and return a :class:`SplatImage` with the same meaning.
"""

from __future__ import annotations

import importlib.util

import torch

from embodied_envs.splat import BACKENDS
from embodied_envs.splat.camera import PinholeCamera
from embodied_envs.splat.model import GaussianSplat, sh_colors
from embodied_envs.splat.rasterizer import (
    LOW_PASS,
    NEAR_Z,
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
    splat: GaussianSplat, camera: PinholeCamera, background: tuple[float, float, float]
) -> SplatImage:
    from gsplat import rasterization

    dev = splat.device
    center = torch.as_tensor(camera.center, dtype=torch.float32, device=dev)
    viewmat = torch.as_tensor(camera.world_to_cam, dtype=torch.float32, device=dev)
    k = torch.as_tensor(camera.intrinsic, dtype=torch.float32, device=dev)
    # colours are evaluated here so that posed splats (sh_frame) get the same SH colour
    colors, alphas, _ = rasterization(
        means=splat.means,
        quats=splat.unit_quats_wxyz,
        scales=splat.scales,
        opacities=splat.opacities,
        colors=sh_colors(splat, center),
        viewmats=viewmat[None],
        Ks=k[None],
        width=camera.width,
        height=camera.height,
        near_plane=NEAR_Z,
        eps2d=LOW_PASS,
        backgrounds=torch.as_tensor(background, dtype=torch.float32, device=dev)[None],
        render_mode="RGB+D",
        packed=False,
    )
    return SplatImage(
        rgb=colors[0, ..., :3].clamp(0.0, 1.0), alpha=alphas[0, ..., 0], depth=colors[0, ..., 3]
    )


def render(
    splat: GaussianSplat,
    camera: PinholeCamera,
    backend: str = "auto",
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> SplatImage:
    """Render ``splat`` (on its own device) from ``camera``.

    Args:
        splat: the Gaussians, already posed in the camera's world frame.
        camera: OpenCV-style pinhole camera.
        backend: ``"auto"``, ``"torch"`` or ``"gsplat"``.
        background: RGB in [0, 1] behind the splat.

    Raises:
        ValueError: the backend is unknown or cannot run on this machine.
    """
    chosen = resolve_backend(backend)
    if chosen == "gsplat":
        if splat.device.type != "cuda":
            splat = splat.to("cuda")
        return _rasterize_gsplat(splat, camera, background)
    return rasterize_torch(splat, camera, background)
