"""Pinhole cameras for splat rendering (OpenCV convention: x right, y down, looking along +z)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# camera-to-world(OpenCV) = camera-to-world(OpenGL) @ GL_TO_CV
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def rigid_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rotation-plus-translation matrix."""
    inv = np.eye(4)
    inv[:3, :3] = m[:3, :3].T
    inv[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return inv


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera with square pixels.

    Attributes:
        world_to_cam: (4, 4) OpenCV-style extrinsics.
        width, height: image size in pixels.
        fx, fy, cx, cy: intrinsics in pixels; pixel (u, v) is centred at (u + 0.5, v + 0.5).
    """

    world_to_cam: np.ndarray
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        m = np.asarray(self.world_to_cam, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise ValueError(f"world_to_cam must be a finite 4x4 matrix, got shape {m.shape}")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        object.__setattr__(self, "world_to_cam", m)

    @classmethod
    def from_fovy(
        cls, world_to_cam: np.ndarray, width: int, height: int, fovy_rad: float
    ) -> PinholeCamera:
        """Pinhole: fy = H / (2 tan(fovy / 2)), fx = fy, principal point at the centre."""
        if not 0.0 < fovy_rad < math.pi:
            raise ValueError(f"fovy must be in (0, 180) degrees, got {math.degrees(fovy_rad)}")
        f = height / (2.0 * math.tan(fovy_rad / 2.0))
        return cls(world_to_cam, int(width), int(height), f, f, width / 2.0, height / 2.0)

    @classmethod
    def look_at(
        cls,
        eye: Sequence[float],
        target: Sequence[float],
        up: Sequence[float] = (0.0, 0.0, 1.0),
        width: int = 256,
        height: int = 256,
        fovy_deg: float = 60.0,
    ) -> PinholeCamera:
        """A camera at ``eye`` looking at ``target`` with image-up as close to ``up`` as possible.

        Raises:
            ValueError: ``eye`` equals ``target`` or ``up`` is parallel to the view direction.
        """
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
        forward = target - eye
        if np.linalg.norm(forward) < 1e-9:
            raise ValueError("camera eye and target coincide; move the target")
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, up)
        if np.linalg.norm(right) < 1e-6:
            raise ValueError("camera up vector is parallel to the view direction; pick another up")
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        cam_to_world = np.eye(4)
        cam_to_world[:3, :3] = np.stack([right, down, forward], axis=1)
        cam_to_world[:3, 3] = eye
        return cls.from_fovy(rigid_inverse(cam_to_world), width, height, math.radians(fovy_deg))

    @classmethod
    def from_opengl(
        cls, cam_to_world_gl: np.ndarray, intrinsic: np.ndarray, width: int, height: int
    ) -> PinholeCamera:
        """From a SAPIEN camera: its OpenGL model matrix and 3x3 intrinsic matrix."""
        cam_to_world = np.asarray(cam_to_world_gl, dtype=np.float64) @ GL_TO_CV
        k = np.asarray(intrinsic, dtype=np.float64)
        return cls(
            rigid_inverse(cam_to_world),
            int(width),
            int(height),
            float(k[0, 0]),
            float(k[1, 1]),
            float(k[0, 2]),
            float(k[1, 2]),
        )

    def in_frame(self, frame_to_world: np.ndarray) -> PinholeCamera:
        """This camera with extrinsics relative to a frame posed at ``frame_to_world`` (4x4):
        a splat stored in that frame, seen by the result, looks like the splat moved by
        ``frame_to_world`` seen by this camera."""
        return dataclasses.replace(
            self, world_to_cam=self.world_to_cam @ np.asarray(frame_to_world, dtype=np.float64)
        )

    def key(self, decimals: int = 6) -> tuple:
        """A hashable identity of the view (pose and intrinsics, rounded): equal keys render
        the same image."""
        pose = tuple(np.round(self.world_to_cam, decimals).reshape(-1).tolist())
        lens = tuple(round(float(v), decimals) for v in (self.fx, self.fy, self.cx, self.cy))
        return (*pose, *lens, self.width, self.height)

    @property
    def center(self) -> np.ndarray:
        """The camera centre in world coordinates."""
        r, t = self.world_to_cam[:3, :3], self.world_to_cam[:3, 3]
        return -r.T @ t

    @property
    def intrinsic(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
