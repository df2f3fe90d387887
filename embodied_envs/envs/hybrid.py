"""Hybrid rendering: simulated foreground composited over a Gaussian-splat background.

Per (camera, env) the background splat is rendered once, posed by that env's layout, and
cached; it is re-rendered only when the camera or the background pose changes. Foreground
pixels are those whose segmentation id is one of the env's foreground ids (robot links and
layout actors, given explicitly); with the depth test on, a foreground pixel farther than the
splat surface shows the background.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from embodied_envs.layout.pose import LayoutPose, quat_multiply_xyzw
from embodied_envs.splat import PinholeCamera, SplatFileError, pose_splat, read_ply, render
from embodied_envs.splat.render import resolve_backend

SPLAT_SURFACE_ALPHA = 0.5  # splat pixels at least this opaque have a surface for the depth test
CAMERA_TOLERANCE = 1e-6  # camera matrices closer than this reuse the cached background


@dataclass(frozen=True)
class CachedBackground:
    """One camera's view of one env's background."""

    camera: PinholeCamera
    pose: LayoutPose
    rgb: torch.Tensor  # (H, W, 3) uint8
    depth: torch.Tensor  # (H, W) float, metres along the camera axis; +inf where no surface

    def matches(self, camera: PinholeCamera, pose: LayoutPose) -> bool:
        c = self.camera
        return (
            pose == self.pose
            and (c.width, c.height) == (camera.width, camera.height)
            and np.allclose(c.intrinsic, camera.intrinsic, atol=CAMERA_TOLERANCE)
            and np.allclose(c.world_to_cam, camera.world_to_cam, atol=CAMERA_TOLERANCE)
        )


class HybridRenderer:
    """Background cache and compositing for one env instance.

    Args:
        splat_path: the background's ``gs_model.ply`` (Y-up, as stored).
        init_quat_xyzw: rotation taking the stored splat to Z-up, applied before the layout pose.
        depth_test: hide foreground pixels behind the splat surface.
        backend: splat backend, ``"auto"``, ``"torch"`` or ``"gsplat"``.
        device: where backgrounds are rendered and kept (the env's device).
        layout_file: named in errors.

    Raises:
        SplatFileError: the splat file is missing or malformed.
        ValueError: the backend cannot run here.
    """

    def __init__(
        self,
        splat_path: str | os.PathLike,
        init_quat_xyzw: tuple[float, float, float, float],
        depth_test: bool = True,
        backend: str = "auto",
        device: torch.device | str = "cpu",
        layout_file: str | os.PathLike = "layout",
    ):
        splat_path = Path(splat_path)
        if not splat_path.is_file():
            raise SplatFileError(
                splat_path,
                f'render_mode="hybrid" needs the background splat of {layout_file}, and this '
                "file does not exist",
                "put a 3DGS gs_model.ply in the background's asset folder (tools/mesh_to_splat.py"
                ' makes one from a mesh) or use render_mode="rgb_array"',
            )
        self.backend = resolve_backend(backend)
        self.device = torch.device(device)
        self.splat = read_ply(splat_path).to(self.device)
        self.init_quat_xyzw = tuple(float(v) for v in init_quat_xyzw)
        self.depth_test = bool(depth_test)
        self._cache: dict[tuple[str, int], CachedBackground] = {}
        self.renders = 0  # background renders so far
        self.render_seconds = 0.0  # time spent in them

    def cached(self, camera_name: str, env: int) -> CachedBackground | None:
        """The cached background of (camera, env), if any."""
        return self._cache.get((camera_name, env))

    def background(
        self, camera_name: str, env: int, camera: PinholeCamera, pose: LayoutPose
    ) -> CachedBackground:
        """The cached background of (camera, env), rendered now if missing or stale."""
        key = (camera_name, env)
        cached = self._cache.get(key)
        if cached is not None and cached.matches(camera, pose):
            return cached
        start = time.perf_counter()
        q = quat_multiply_xyzw(pose.q_xyzw, self.init_quat_xyzw)  # init first, then layout
        posed = pose_splat(self.splat, torch.tensor(pose.p), torch.tensor(q[[3, 0, 1, 2]]))
        image = render(posed, camera, backend=self.backend)
        cached = CachedBackground(
            camera=camera,
            pose=pose,
            rgb=image.rgb_uint8().to(self.device),
            depth=image.surface_depth(SPLAT_SURFACE_ALPHA).to(self.device),
        )
        self._cache[key] = cached
        self.renders += 1
        self.render_seconds += time.perf_counter() - start
        return cached

    def backgrounds(
        self,
        camera_name: str,
        cam_to_world_gl: torch.Tensor,
        intrinsic: torch.Tensor,
        width: int,
        height: int,
        background_poses: list[LayoutPose],
    ) -> list[CachedBackground]:
        """Every env's background for one camera (rendered where missing or stale).

        Args:
            camera_name: cache key of the camera.
            cam_to_world_gl: (n, 4, 4) SAPIEN model matrices (OpenGL convention).
            intrinsic: (n, 3, 3) OpenCV intrinsics.
            width, height: image size.
            background_poses: per env, the layout pose of the background node.
        """
        model = cam_to_world_gl.detach().cpu().double().numpy()
        k = intrinsic.detach().cpu().double().numpy()
        return [
            self.background(
                camera_name,
                env,
                PinholeCamera.from_opengl(model[env], k[env], width, height),
                pose,
            )
            for env, pose in enumerate(background_poses)
        ]

    def composite(
        self,
        camera_name: str,
        rgb: torch.Tensor,
        segmentation: torch.Tensor,
        depth_mm: torch.Tensor,
        cam_to_world_gl: torch.Tensor,
        intrinsic: torch.Tensor,
        foreground_ids: list[torch.Tensor],
        background_poses: list[LayoutPose],
    ) -> torch.Tensor:
        """Composite a batch of camera images over their backgrounds.

        Args:
            camera_name: cache key of the camera.
            rgb: (n, H, W, 3) uint8 simulated colour.
            segmentation: (n, H, W, 1) per-scene actor/link ids.
            depth_mm: (n, H, W, 1) depth in millimetres (ManiSkill's ``depth`` texture).
            cam_to_world_gl: (n, 4, 4) SAPIEN model matrices (OpenGL convention).
            intrinsic: (n, 3, 3) OpenCV intrinsics.
            foreground_ids: per env, the ids that are foreground.
            background_poses: per env, the layout pose of the background node.

        Returns:
            (n, H, W, 3) uint8.
        """
        n, h, w = rgb.shape[:3]
        backgrounds = self.backgrounds(
            camera_name, cam_to_world_gl, intrinsic, w, h, background_poses
        )
        out = torch.empty_like(rgb)
        for env, bg in enumerate(backgrounds):
            seg = segmentation[env, ..., 0].long()
            ids = foreground_ids[env].to(seg.device, torch.long)
            lookup = torch.zeros(
                int(max(seg.max(), ids.max())) + 1, dtype=torch.bool, device=seg.device
            )
            lookup[ids] = True
            mask = lookup[seg]
            if self.depth_test:
                fg_depth = depth_mm[env, ..., 0].to(torch.float32) / 1000.0
                mask &= fg_depth <= bg.depth.to(fg_depth.device)
            out[env] = torch.where(mask[..., None], rgb[env], bg.rgb.to(rgb.device))
        return out
