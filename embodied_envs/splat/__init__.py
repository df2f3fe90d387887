"""Gaussian splats: PLY files, posing, rasterizers (PyTorch on CPU/CUDA, gsplat) and meshes.

Independent of the rest of the package; the env imports it for ``render_mode="hybrid"``.
Names are imported on first use, so reading and checking a PLY file (:mod:`.ply`, numpy only)
does not import torch.
"""

import importlib

BACKENDS = ("auto", "torch", "gsplat")  # splat renderers; "auto": gsplat when it can run

_EXPORTS = {
    "GaussianSplat": "model",
    "PinholeCamera": "camera",
    "SplatFileError": "ply",
    "SplatImage": "rasterizer",
    "check_ply": "ply",
    "mesh_file_to_splat": "mesh",
    "mesh_to_splat": "mesh",
    "pose_splat": "model",
    "rasterize_torch": "rasterizer",
    "read_ply": "ply",
    "render": "backend",
    "write_ply": "ply",
}
__all__ = ["BACKENDS", *sorted(_EXPORTS)]


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
