"""Pose conversions: the one module that knows quaternion orders.

Layout files store ``[x, y, z, qx, qy, qz, qw]`` (scalar-LAST). SAPIEN's ``sapien.Pose(p, q)``
takes ``q = [qw, qx, qy, qz]`` (scalar-FIRST) and ManiSkill's raw pose is
``[x, y, z, qw, qx, qy, qz]``. Every conversion between them goes through :class:`LayoutPose`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

QUAT_NORM_TOLERANCE = 1e-3  # |q| may deviate this much from 1 and is then normalised


def quat_multiply_xyzw(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Hamilton product ``a * b`` of two scalar-last quaternions (rotate by b, then by a)."""
    return (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat()


def yaw_quat_xyzw(yaw: float) -> np.ndarray:
    """Scalar-last quaternion of a rotation by ``yaw`` radians about +Z."""
    return np.array([0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)])


@dataclass(frozen=True)
class LayoutPose:
    """A rigid pose as layout files write it: position and a scalar-last unit quaternion."""

    p: tuple[float, float, float]
    q_xyzw: tuple[float, float, float, float]

    @classmethod
    def from_layout(cls, values: Sequence[float]) -> LayoutPose:
        """From a layout list ``[x, y, z, qx, qy, qz, qw]``; the quaternion is normalised."""
        v = np.asarray(values, dtype=np.float64)
        if v.shape != (7,):
            raise ValueError(f"a layout pose has 7 numbers, got {v.size}")
        q = v[3:] / np.linalg.norm(v[3:])
        return cls(tuple(float(x) for x in v[:3]), tuple(float(x) for x in q))

    @classmethod
    def from_raw(cls, raw: Sequence[float]) -> LayoutPose:
        """From a ManiSkill raw pose ``[x, y, z, qw, qx, qy, qz]``."""
        r = np.asarray(raw, dtype=np.float64).reshape(7)
        return cls.from_layout([*r[:3], r[4], r[5], r[6], r[3]])

    @classmethod
    def from_xyz_yaw(cls, xyz: Sequence[float], yaw: float) -> LayoutPose:
        return cls(tuple(float(x) for x in xyz), tuple(float(x) for x in yaw_quat_xyzw(yaw)))

    @property
    def q_wxyz(self) -> tuple[float, float, float, float]:
        x, y, z, w = self.q_xyzw
        return (w, x, y, z)

    def to_layout(self, decimals: int | None = None) -> list[float]:
        """``[x, y, z, qx, qy, qz, qw]``, optionally rounded (as written to JSON)."""
        values = [*self.p, *self.q_xyzw]
        if decimals is not None:
            values = [round(float(v), decimals) for v in values]
        return values

    def to_raw(self) -> np.ndarray:
        """ManiSkill raw pose ``[x, y, z, qw, qx, qy, qz]`` as float32."""
        return np.array([*self.p, *self.q_wxyz], dtype=np.float32)

    def to_sapien(self):
        """A ``sapien.Pose`` (scalar-first quaternion)."""
        import sapien  # only for the simulator: layout commands start without SAPIEN

        return sapien.Pose(p=list(self.p), q=list(self.q_wxyz))

    def rotation_matrix(self) -> np.ndarray:
        return Rotation.from_quat(self.q_xyzw).as_matrix()

    def matrix(self) -> np.ndarray:
        """The pose as a 4x4 homogeneous transform (child frame to parent frame)."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.rotation_matrix(), self.p
        return m

    def transform_points(self, points: np.ndarray) -> np.ndarray:
        """Map ``(n, 3)`` points from this pose's frame to the parent frame."""
        return np.asarray(points) @ self.rotation_matrix().T + np.asarray(self.p)

    @property
    def yaw(self) -> float:
        """Heading: angle of the frame's +X axis projected on the XY plane."""
        x, y, z, w = self.q_xyzw  # first column of the rotation matrix, written out
        return math.atan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))

    def raised(self, dz: float) -> LayoutPose:
        """The same pose moved up by ``dz`` metres (z only)."""
        return LayoutPose((self.p[0], self.p[1], self.p[2] + dz), self.q_xyzw)


def wrap_angle(angle):
    """An angle (float, numpy array or torch tensor) wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def rpy_to_matrix(rpy: Sequence[float]) -> np.ndarray:
    """URDF ``rpy`` (fixed-axis roll, pitch, yaw) as a rotation matrix."""
    return Rotation.from_euler("xyz", rpy).as_matrix()


def rpy_to_quat_wxyz(rpy: Sequence[float]) -> tuple[float, float, float, float]:
    x, y, z, w = Rotation.from_euler("xyz", rpy).as_quat()
    return (float(w), float(x), float(y), float(z))
