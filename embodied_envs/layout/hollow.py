"""Whether convex parts fill a hollow of a surface: the one rule that decides it, wherever a
surface is compared with the convex parts that stand for it (a collision object with the hull
the simulator makes of it, a decomposition with its piece, a visual mesh with its collision).

A grid of vertical rays over the surface's footprint, in the object's frame as it rests (Z up),
finds at each interior probe the highest point of the surface (:func:`surface_tops`), where a
thing set there would rest; where that point lies on a floor (a face tilted at most
``FLOOR_TILT``) and the convex parts' top there (:func:`part_tops`) stands higher by more than
``HOLLOW_TOLERANCE``, the parts fill a hollow: a thing set in it would float. The rule reads
geometry only, so an open surface, several objects or a shallow recess cannot hide a hollow
(a hull/volume ratio misses a 1 cm recess in a 3 cm tray and cannot be measured on an open
surface). An open surface is made solid by :func:`shell` (a closed shell ``SHELL_THICKNESS``
thick around it) before it is decomposed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

HOLLOW_TOLERANCE = 2e-3  # m: parts standing higher than the surface by more fill a hollow
PROBES = 32  # probes along the longer side of the surface's footprint
REACH = 2  # probes each way along the grid over which a hollow must hold (it must be 4 probes
# wide: an eighth of the footprint)
PROBE_MARGIN = 0.03  # share of the footprint's longer side kept clear of its outline (at least
# HOLLOW_TOLERANCE): rays there graze outer walls
FLOOR_TILT = np.cos(np.radians(40))  # |n_z| of a face a probe reads as a floor: a thing rests
# on it (steeper walls turn a sideways millimetre into several vertical ones)
SHELL_THICKNESS = 2e-3  # m: an open surface made solid is this thick, half each side


@dataclass(frozen=True)
class Hollow:
    """The worst probe: how far the parts stand over the surface's floor there."""

    gap: float  # m; -inf when no interior probe finds a floor under the parts
    xy: tuple[float, float]  # the probe, in the object's frame
    floor: float  # m: the surface's height there

    @property
    def filled(self) -> bool:
        return self.gap > HOLLOW_TOLERANCE

    def words(self) -> str:
        return (
            f"a hollow filled {self.gap * 1000:.1f} mm over its floor (at x {self.xy[0]:.3f}, "
            f"y {self.xy[1]:.3f} m in the object's frame, Z up)"
        )


def surface_tops(triangles: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The highest point of a surface (``(f, 3, 3)`` triangles, Z up) over each of the ``(p, 2)``
    points ``xy``, and ``|n_z|`` of the face it lies on; ``-inf`` and 0 where none."""
    tri = np.asarray(triangles, dtype=np.float64)
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    normal = np.cross(e1, e2)
    length = np.linalg.norm(normal, axis=1)
    det = normal[:, 2]
    keep = np.abs(det) > 1e-9 * np.maximum(length, 1e-30)  # a vertical face: no vertical hit
    a, e1, e2, det = a[keep], e1[keep], e2[keep], det[keep]
    tilt = np.abs(det) / length[keep]
    lo, hi = tri[keep, :, 1].min(1), tri[keep, :, 1].max(1)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    top, slope = np.full(len(xy), -np.inf), np.zeros(len(xy))
    eps = 1e-9
    for y in np.unique(xy[:, 1]):  # the probes row by row: only the faces the row crosses
        rows = np.flatnonzero(xy[:, 1] == y)
        f = np.flatnonzero((lo <= y + eps) & (hi >= y - eps))
        if not len(f):
            continue
        d = xy[rows, None, :] - a[None, f, :2]  # (r, f, 2)
        u = (d[..., 0] * e2[f, 1] - d[..., 1] * e2[f, 0]) / det[f]
        v = (e1[f, 0] * d[..., 1] - e1[f, 1] * d[..., 0]) / det[f]
        inside = (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
        z = np.where(inside, a[f, 2] + u * e1[f, 2] + v * e2[f, 2], -np.inf)
        best = z.argmax(1)
        top[rows] = z[np.arange(len(rows)), best]
        slope[rows] = np.where(np.isfinite(top[rows]), tilt[f][best], 0.0)
    return top, slope


def part_tops(parts: list[np.ndarray], xy: np.ndarray) -> np.ndarray:
    """The highest z inside any of the convex ``parts`` (vertex arrays, Z up) over each of the
    ``(p, 2)`` points ``xy``: where a thing dropped there rests; ``-inf`` where no part is."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    best = np.full(len(xy), -np.inf)
    for verts in parts:
        try:
            eq = ConvexHull(verts).equations  # a . p + d <= 0 inside
        except QhullError:  # flat: nothing rests in it (refused or kept elsewhere)
            continue
        rhs = -(eq[None, :, 3] + xy @ eq[:, :2].T)  # (p, faces): a_z z <= rhs
        az = eq[:, 2]
        up, down = az > 1e-12, az < -1e-12
        flat = ~(up | down)
        high = (rhs[:, up] / az[up]).min(1) if up.any() else np.full(len(xy), np.inf)
        low = (rhs[:, down] / az[down]).max(1) if down.any() else np.full(len(xy), -np.inf)
        ok = (low <= high + 1e-12) & (rhs[:, flat] >= -1e-12).all(1)
        best = np.where(ok, np.maximum(best, high), best)
    return best


def probes(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A grid over the footprint of ``vertices`` (Z up), ``PROBES`` along its longer side:
    the ``(nx, ny, 2)`` probes, and which are interior (at least ``PROBE_MARGIN`` of that side
    inside the footprint's hull)."""
    xy = np.asarray(vertices, dtype=np.float64)[:, :2]
    lo, hi = xy.min(0), xy.max(0)
    size = float((hi - lo).max())
    step = max(size, 1e-9) / PROBES
    axes = [np.arange(lo[k] + step / 2, hi[k], step) for k in (0, 1)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    try:
        eq = ConvexHull(xy).equations  # a . p + d <= 0 inside
    except QhullError:  # a footprint of no area (a line): no interior
        return grid, np.zeros(grid.shape[:2], bool)
    margin = max(HOLLOW_TOLERANCE, PROBE_MARGIN * size)
    return grid, (grid @ eq[:, :2].T + eq[:, 2] <= -margin).all(-1)


def filled_hollow(triangles: np.ndarray, parts: list[np.ndarray]) -> Hollow:
    """How far the convex ``parts`` stand over the floors of a surface (``(f, 3, 3)``
    triangles), at the worst interior probe (both Z up, in the object's frame). A probe counts
    the least gap within ``REACH`` probes of it along the grid's rows and columns: a hollow is
    a floor the parts cover, not a part's edge a millimetre past the foot of a wall."""
    tri = np.asarray(triangles, dtype=np.float64)
    grid, interior = probes(tri.reshape(-1, 3))
    gap = np.full(interior.shape, -np.inf)
    if interior.any() and parts:
        xy = grid[interior]
        top, slope = surface_tops(tri, xy)
        solid = part_tops(parts, xy)
        floor = (slope >= FLOOR_TILT) & np.isfinite(top) & np.isfinite(solid)
        with np.errstate(invalid="ignore"):  # -inf - -inf where neither is found
            gap[interior] = np.where(floor, solid - top, -np.inf)
        tops = np.full(interior.shape, np.nan)
        tops[interior] = top
    least = gap.copy()
    padded = np.pad(gap, REACH, constant_values=-np.inf)
    n, m = gap.shape
    for d in range(-REACH, REACH + 1):
        least = np.minimum(least, padded[REACH + d : REACH + d + n, REACH : REACH + m])
        least = np.minimum(least, padded[REACH : REACH + n, REACH + d : REACH + d + m])
    k = np.unravel_index(int(least.argmax()), least.shape)
    if not np.isfinite(least[k]):
        return Hollow(-np.inf, (0.0, 0.0), 0.0)
    return Hollow(float(least[k]), (float(grid[k][0]), float(grid[k][1])), float(tops[k]))


def shell(mesh):
    """A closed shell ``SHELL_THICKNESS`` thick around an open surface (its vertices moved half
    of it along their normals each way, the boundary stitched), or ``None`` when the surface is
    not one consistently wound sheet."""
    import trimesh  # only where a mesh is read

    m = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    trimesh.repair.fix_winding(m)
    if not m.is_winding_consistent:
        return None
    n, v = len(m.vertices), m.vertices
    offset = m.vertex_normals * SHELL_THICKNESS / 2
    edges = m.edges[trimesh.grouping.group_rows(m.edges_sorted, require_count=1)]
    i, j = edges[:, 0], edges[:, 1]  # each boundary edge as its face runs it
    side = np.concatenate([np.stack([j, i, i + n], 1), np.stack([j, i + n, j + n], 1)])
    faces = np.concatenate([m.faces, m.faces[:, ::-1] + n, side])
    out = trimesh.Trimesh(np.concatenate([v + offset, v - offset]), faces, process=False)
    if not out.is_watertight:
        return None
    if out.volume < 0:
        out.invert()
    return out
