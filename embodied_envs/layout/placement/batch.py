"""Arrays over a batch of envs, for the per-episode sampler (``episode.EpisodeSampler``).

- counter-based random numbers: every uniform is a splitmix64 hash of (key, stream, index), so
  an env's numbers depend on its own episode key only (:func:`uniforms`, :func:`normals`);
- where the arrays live: numpy on a CPU env, torch on the env's device otherwise
  (:class:`Arrays`); the placement rules run unchanged on either (``rules.array_module``);
- the shapes placed (:class:`Shapes`) and the convex regions they are placed in
  (:class:`Region`), one row per env.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

from embodied_envs.layout.placement.rules import (
    amax,
    amin,
    array_module,
    half_planes,
    inside,
    inward_normals,
    pad_polygons,
    stack_last,
)

# --- counter-based random numbers ----------------------------------------------------------
_GOLDEN = 0x9E3779B97F4A7C15  # splitmix64 constants
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB


def _int64(x: int) -> int:
    """A 64-bit constant as the signed value int64 arithmetic wraps around."""
    return x - (1 << 64) if x >= 1 << 63 else x


def _shift_right(z, k: int):
    """Logical right shift of int64 (numpy's and torch's ``>>`` are arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


def _as(x, dtype: str):
    """``x`` as ``dtype`` (a name), in its own library and on its own device."""
    return x.astype(dtype) if isinstance(x, np.ndarray) else x.to(getattr(torch, dtype))


def uniforms(keys, stream: int, n: int):
    """``(b, n)`` float32 uniforms in [0, 1), a splitmix64 hash of (key, stream, index).

    Args:
        keys: ``(b,)`` integer key per env (numpy or torch; the result is the same library's).
        stream: which sequence of the key (objects, goal, noise use different streams).
        n: numbers per env.
    """
    if isinstance(keys, np.ndarray):
        index = np.arange(n, dtype=np.int64)
    else:
        index = torch.arange(n, device=keys.device, dtype=torch.int64)
    z = _as(keys, "int64")[:, None] * _int64(_GOLDEN) + (index + (stream << 32))
    z = (z ^ _shift_right(z, 30)) * _int64(_MIX1)
    z = (z ^ _shift_right(z, 27)) * _int64(_MIX2)
    z = z ^ _shift_right(z, 31)
    return _as(_shift_right(z, 40), "float32") * 2.0**-24  # 24 bits: exact in float32


def normals(keys, stream: int, n: int):
    """``(b, n)`` standard normal numbers (Box-Muller over :func:`uniforms`)."""
    xp = array_module(keys)
    u = uniforms(keys, stream, 2 * n).reshape(-1, 2, n)
    return xp.sqrt(-2.0 * xp.log1p(-u[:, 0])) * xp.cos(2 * math.pi * u[:, 1])


# --- arrays of a sampler: numpy on the CPU, torch elsewhere ----------------------------------
class Arrays:
    """Where a sampler's arrays live: ``numpy`` (float32) for a CPU env, ``torch`` on the
    env's device otherwise; ``backend`` forces one (tests run the torch path on the CPU)."""

    def __init__(self, device: torch.device | str, backend: str | None = None):
        self.device = torch.device(device)
        if backend is None:
            backend = "numpy" if self.device.type == "cpu" else "torch"
        if backend not in ("numpy", "torch"):
            raise ValueError(f"backend={backend!r} must be 'numpy' or 'torch'")
        self.xp = np if backend == "numpy" else torch

    def __call__(self, x, dtype: str = "float32"):
        """``x`` (numbers, a numpy array or a tensor) as this backend's array of ``dtype``."""
        if self.xp is np:
            if isinstance(x, torch.Tensor):
                x = x.detach().cpu().numpy()
            return np.asarray(x, dtype=dtype)
        if not isinstance(x, torch.Tensor):
            x = np.array(x)  # a copy: cached asset arrays are read-only
        return torch.as_tensor(x, dtype=getattr(torch, dtype), device=self.device)

    def zeros(self, shape, dtype: str = "float32"):
        if self.xp is np:
            return np.zeros(shape, dtype=dtype)
        return torch.zeros(shape, dtype=getattr(torch, dtype), device=self.device)

    def index(self, idx):
        """Env indices (a tensor, array or list) as this backend's int64 array."""
        return self(idx, "int64")

    @staticmethod
    def numpy(x) -> np.ndarray:
        """``x`` (either backend's array) as a numpy array."""
        return x if isinstance(x, np.ndarray) else x.detach().cpu().numpy()

    def tensor(self, x) -> torch.Tensor:
        """A result for the env: a tensor on its device (numpy arrays are shared, not copied,
        on the CPU)."""
        return torch.as_tensor(x, device=self.device)


@dataclass(frozen=True)
class Shapes:
    """Convex polygons in their own frames, as the placement rules take them.

    Padded to a common vertex count ``M`` (``rules.pad_polygons``).

    Attributes:
        vertices: ``(S, M, 2)`` counter-clockwise vertices.
        normals: ``(S, M, 2)`` inward unit edge normals.
        radii: ``(S,)`` bounding radius about the frame's origin.
    """

    vertices: object
    normals: object
    radii: object

    @classmethod
    def of(cls, polygons: list[np.ndarray], arrays: Arrays) -> Shapes:
        verts = pad_polygons(polygons)
        radii = np.linalg.norm(verts, axis=-1).max(-1)
        return cls(arrays(verts), arrays(inward_normals(verts)), arrays(radii))


def yaw_raw_poses(xy, z, yaw):
    """ManiSkill raw poses ``(b, 7)``, ``[x, y, z, qw, qx, qy, qz]``, of yaw-only rotations."""
    xp = array_module(yaw)
    zeros = xp.zeros_like(yaw)
    return stack_last([xy[:, 0], xy[:, 1], z, xp.cos(yaw / 2), zeros, zeros, xp.sin(yaw / 2)])


@dataclass(frozen=True)
class Region:
    """Convex regions per env: ``inside(x) iff normals @ x >= offsets``, with their boxes
    (numpy arrays or tensors)."""

    normals: object  # (b, e, 2)
    offsets: object  # (b, e)
    lo: object  # (b, 2)
    hi: object  # (b, 2)
    z: object  # (b,) height of the surface

    @classmethod
    def of(cls, poly, z) -> Region:
        n, c = half_planes(poly)
        return cls(n, c, amin(poly, -2), amax(poly, -2), z)

    def map(self, fn) -> Region:
        """The region with ``fn`` applied to every array (e.g. to make tensors of them)."""
        return Region(*(fn(getattr(self, f.name)) for f in fields(self)))

    def rows(self, idx) -> Region:
        return self.map(lambda x: x[idx])

    def candidates(self, u):
        """Candidate positions ``(b, k, 2)`` uniform over each env's box and yaws ``(b, k)``,
        from uniforms ``u (b, 3, k)``."""
        lo, hi = self.lo[:, None], self.hi[:, None]
        return lo + u[:, :2].swapaxes(-1, -2) * (hi - lo), (2 * u[:, 2] - 1) * math.pi

    def contains(self, points):
        """``points (b, ..., 2)`` -> ``(b, ...)`` bool (``rules.inside`` of each point)."""
        b = self.offsets.shape[0]
        flat = points.reshape(b, -1, 1, 2)  # each point a one-vertex polygon
        ok = inside(flat, self.normals[:, None], self.offsets[:, None])
        return ok.reshape(points.shape[:-1])
