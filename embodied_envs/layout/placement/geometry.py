"""The geometry placement reads from assets: footprints, tops and bottoms, and plane polygons.

Every value derived from an asset's collision geometry is kept in ``ASSET_FILES`` under the
asset's :data:`AssetKey` (the versions of its URDF and collision mesh), so an edited file is
read again and an unchanged one is read once per process.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from embodied_envs.layout.assets import (
    ASSET_FILES,
    AssetGeometry,
    FileVersion,
    asset_geometry,
    convex_hull_2d,
    parse_urdf,
    urdf_path_for,
)
from embodied_envs.layout.placement.rules import half_planes, rotate
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.layout.schema import LayoutInfo

AssetKey = tuple[FileVersion, FileVersion]  # (URDF, collision mesh) of a node's asset


class Top(NamedTuple):
    """The top of an asset in its own actor frame."""

    hull: np.ndarray  # (m, 2) CCW hull of the vertices within the top band of the highest
    z: float  # height of the highest point
    shrunk: np.ndarray | None  # the hull moved inward by the margin; None when it vanishes


def asset_key(layout: LayoutInfo, node: str) -> AssetKey:
    """The versions of a node's URDF and collision mesh: the key of every value derived from
    its geometry (``ASSET_FILES``), so an edited file is read again."""
    urdf = FileVersion.of(str(urdf_path_for(Path(layout.asset_base, layout.assets[node]), node)))
    return urdf, FileVersion.of(_spec(urdf).collision.path)


def _spec(urdf: FileVersion):
    return ASSET_FILES.get(("urdf", urdf), lambda: parse_urdf(Path(urdf.path)))


def key_geometry(key: AssetKey) -> AssetGeometry:
    """The collision geometry of the asset ``key``."""
    return asset_geometry(_spec(key[0]), key[1])


def key_footprint(key: AssetKey) -> np.ndarray:
    """2D convex footprint ``(m, 2)`` of the asset ``key`` in its own frame (CCW)."""
    return ASSET_FILES.get(("footprint", key), lambda: key_geometry(key).footprint())


def key_bottom(key: AssetKey, percentile: float) -> float:
    """The asset's lowest point in its own frame, as a percentile of its vertices' heights."""
    return ASSET_FILES.get(
        ("bottom", key, percentile),
        lambda: float(np.percentile(key_geometry(key).vertices[:, 2], percentile)),
    )


def key_top(key: AssetKey, band: float, margin: float) -> Top:
    """The top of the asset ``key`` in its own frame, its hull shrunk by ``margin``."""

    def compute():
        geom = key_geometry(key)
        hull = geom.top_hull(band)
        try:
            shrunk = shrink_polygon(hull, margin)
        except ValueError:
            shrunk = None
        return Top(hull, geom.max_z, shrunk)

    return ASSET_FILES.get(("top", key, band, margin), compute)


def node_geometry(layout: LayoutInfo, node: str) -> AssetGeometry:
    """Collision geometry of a node's asset (parsed once per file version)."""
    return key_geometry(asset_key(layout, node))


def node_footprint(layout: LayoutInfo, node: str) -> np.ndarray:
    """2D convex footprint ``(m, 2)`` of a node in its own actor frame (counter-clockwise)."""
    return key_footprint(asset_key(layout, node))


def local_top(layout: LayoutInfo, node: str, band: float, margin: float) -> Top:
    """The top of a node's asset in its own actor frame."""
    return key_top(asset_key(layout, node), band, margin)


@dataclass(frozen=True)
class Surface:
    """The top of a placed support: its hull (world XY, CCW), height, and the hull shrunk by
    the placement margin (None when the top is too small to shrink)."""

    hull: np.ndarray
    z: float
    shrunk: np.ndarray | None = None


def posed_top(top: Top, pose: LayoutPose) -> Surface:
    """A :class:`Top` (its own frame) of an asset standing upright at ``pose`` (yaw only).

    Shrinking commutes with rotation and translation, so the shrunk hull is computed once per
    asset in its own frame.
    """
    yaw, xy = np.float64(pose.yaw), np.asarray(pose.p[:2])
    return Surface(
        rotate(top.hull, yaw) + xy,
        top.z + pose.p[2],
        None if top.shrunk is None else rotate(top.shrunk, yaw) + xy,
    )


def world_vertices(geom: AssetGeometry, pose: LayoutPose) -> np.ndarray:
    return pose.transform_points(geom.vertices)


def top_surface(vertices: np.ndarray, band: float) -> Surface:
    """The top of world vertices ``(n, 3)``: the hull of those within ``band`` of the highest."""
    top_z = float(vertices[:, 2].max())
    top = vertices[vertices[:, 2] >= top_z - band]
    return Surface(convex_hull_2d(top[:, :2]), top_z)


def polygon_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def polygon_centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    if abs(area) < 1e-12:
        return poly.mean(axis=0)
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def shrink_polygon(poly: np.ndarray, margin: float) -> np.ndarray:
    """The CCW convex polygon moved inward by ``margin`` on every edge."""
    n, c = half_planes(poly)
    c = c + margin
    n0, c0 = np.roll(n, 1, axis=0), np.roll(c, 1)  # edge i-1 meets edge i at vertex i
    det = n0[:, 0] * n[:, 1] - n0[:, 1] * n[:, 0]
    ok = np.abs(det) > 1e-12
    x = (c0 * n[:, 1] - n0[:, 1] * c)[ok] / det[ok]
    y = (n0[:, 0] * c - c0 * n[:, 0])[ok] / det[ok]
    pts = np.stack([x, y], 1)
    keep = np.all(pts @ n.T >= c - 1e-9, axis=1) if len(pts) else np.zeros(0, bool)
    if keep.sum() < 3:
        raise ValueError(f"polygon vanishes when shrunk by {margin} m")
    return convex_hull_2d(pts[keep])


def square(center: np.ndarray, side: float, yaw: float) -> np.ndarray:
    """The square of side ``side`` about ``center`` turned by ``yaw`` (the robot base)."""
    h = side / 2.0
    local = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    return rotate(local, np.float64(yaw)) + center[:2]
