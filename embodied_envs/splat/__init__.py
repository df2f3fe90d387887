"""Gaussian splats: PLY files, posing, rasterizers (PyTorch on CPU/CUDA, gsplat) and meshes.

Independent of the rest of the package; the env imports it for ``render_mode="hybrid"``.
"""

from embodied_envs.splat.camera import PinholeCamera
from embodied_envs.splat.mesh import mesh_to_splat
from embodied_envs.splat.model import GaussianSplat, pose_splat
from embodied_envs.splat.ply import SplatFileError, read_ply, write_ply
from embodied_envs.splat.rasterizer import SplatImage, rasterize_torch
from embodied_envs.splat.render import render

__all__ = [
    "GaussianSplat",
    "PinholeCamera",
    "SplatFileError",
    "SplatImage",
    "mesh_to_splat",
    "pose_splat",
    "rasterize_torch",
    "read_ply",
    "render",
    "write_ply",
]
