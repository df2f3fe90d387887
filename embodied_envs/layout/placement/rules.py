"""The placement rules, defined once: where an object may stand.

- **inside**: its whole footprint inside its support's top (shrunk by the hull margin);
- **clear**: its footprint no closer than the clearance to any placed footprint (the robot
  base's square included), by the separating-axis test;
- **within reach**: a manipulated object's centre within the robot's distance band and heading
  cone (goals use the same rule with the band shrunk by ``GoalRegion.inset``);
- **its destination too**: a ``move`` task's mover also has its footprint inside the top, its
  centre within reach and its footprint clear of the placed footprints where the task takes it
  (``Task.shift``, in the robot's frame); the objects placed after it keep clear of that
  destination footprint as of its start (``tree.Standing.avoid_destinations``).

Both placements use these functions: per configuration (``configuration.place``, numpy,
float64) and per episode (``episode.EpisodeSampler``, numpy on the CPU, torch on a GPU).
Every function takes the arrays of either library and computes with that library's operations
(:func:`array_module`), so the rule is the same code whichever array it runs on. The limits
themselves live in ``limits.py``.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from embodied_envs.layout.pose import wrap_angle

INSIDE_TOLERANCE = 1e-9  # m: a vertex this far outside a half-plane still counts as inside


def array_module(x):
    """``torch`` for a torch tensor, else ``numpy`` (torch is never imported here: a tensor
    exists only where torch already is)."""
    torch = sys.modules.get("torch")
    return torch if torch is not None and isinstance(x, torch.Tensor) else np


def stack_last(parts):
    """``xp.stack(parts, -1)`` of same-shaped arrays; numpy's by ``concatenate`` (the same
    array, a fraction of ``np.stack``'s fixed cost, which dominates the few-env draws)."""
    if array_module(parts[0]) is np:
        return np.concatenate([p[..., None] for p in parts], -1)
    return sys.modules["torch"].stack(parts, -1)


def amax(x, dim: int = -1):
    """The maximum over ``dim`` (numpy's method: ``np.amax``'s wrapper costs more)."""
    return x.max(dim) if array_module(x) is np else x.amax(dim)


def amin(x, dim: int = -1):
    """The minimum over ``dim``."""
    return x.min(dim) if array_module(x) is np else x.amin(dim)


def all_true(mask):
    """A bool array of ``mask``'s shape and library, all True."""
    if array_module(mask) is np:
        return np.ones(mask.shape, dtype=bool)
    return sys.modules["torch"].ones_like(mask, dtype=sys.modules["torch"].bool)


def rotate(points, yaw):
    """``points (m, 2)`` rotated by each ``yaw (...)``: ``(..., m, 2)``; or points
    ``(..., m, 2)`` each by its own yaw ``(...)``."""
    xp = array_module(yaw)
    c, s = xp.cos(yaw)[..., None], xp.sin(yaw)[..., None]
    x, y = points[..., 0], points[..., 1]
    return stack_last([c * x - s * y, s * x + c * y])


def inward_normals(poly):
    """Inward unit edge normals of counter-clockwise polygons ``(..., m, 2)`` (edge i runs
    from vertex i to i + 1); a zero-length edge gets a zero normal."""
    xp = array_module(poly)
    e = xp.roll(poly, -1, -2) - poly
    n = stack_last([-e[..., 1], e[..., 0]])
    return n / xp.clip(xp.hypot(n[..., 0], n[..., 1]), 1e-12, None)[..., None]


def pad_polygons(polygons) -> np.ndarray:
    """Polygons ``[(m_i, 2)]`` as one array ``(n, max m_i, 2)``, each padded by repeating its
    last vertex: the padded edges have zero length and zero normals, which are never
    separating axes (:func:`overlap`) and change no support."""
    size = max(len(p) for p in polygons)
    return np.array([np.concatenate([p, np.repeat(p[-1:], size - len(p), 0)])
                     for p in polygons])  # fmt: skip


def half_planes(poly):
    """``(normals, offsets)`` of a CCW polygon: a point p is inside iff ``normals @ p >=
    offsets`` on every edge."""
    n = inward_normals(poly)
    return n, (n * poly).sum(-1)


def inside(vertices, normals, offsets):
    """Whether every vertex of each polygon lies in the region (the footprint inside the top).

    Args:
        vertices: ``(..., m, 2)`` polygons.
        normals, offsets: ``(..., e, 2)`` and ``(..., e)`` the region's :func:`half_planes`,
            broadcasting against the polygons' leading dims.

    Returns:
        ``(...)`` bool.
    """
    depth = vertices @ normals.swapaxes(-1, -2)  # (..., m, e)
    ok = depth >= offsets[..., None, :] - INSIDE_TOLERANCE
    return ok.reshape(*ok.shape[:-2], -1).all(-1)  # one reduction over (m, e)


def overlap(p, q, clearance, p_normals, q_normals):
    """Separating-axis test of convex polygons (the footprints clear of each other).

    Args:
        p: ``(..., m, 2)`` polygons.
        q: ``(..., k, 2)`` polygons, paired with p (leading dims broadcast).
        clearance: polygons closer than this along every axis count as overlapping (a
            float, or an array broadcasting against ``(..., a)``).
        p_normals, q_normals: their :func:`inward_normals`; zero (padding) normals are
            never separating axes.

    Returns:
        ``(...)`` bool, True where a pair overlaps or is closer than ``clearance``.
    """
    xp = array_module(p)
    lead = p_normals.shape[:-2]
    q_normals = xp.broadcast_to(q_normals, (*lead, *q_normals.shape[-2:]))
    axes = xp.concatenate([p_normals, q_normals], -2)  # (..., a, 2)
    on_p = axes @ p.swapaxes(-1, -2)  # (..., a, m)
    on_q = axes @ q.swapaxes(-1, -2)
    real = (axes != 0).any(-1)
    apart = (amax(on_p) + clearance <= amin(on_q)) | (
        amax(on_q) + clearance <= amin(on_p)
    )
    return ~(apart & real).any(-1)


def heading_error(rel, yaw):
    """``|angle(rel) - yaw|`` wrapped to [0, pi]; ``yaw`` broadcasts against ``rel[..., 0]``."""
    xp = array_module(rel)
    return xp.abs(wrap_angle(xp.arctan2(rel[..., 1], rel[..., 0]) - yaw))


def within_reach(xy, robot_xy, robot_yaw, band: tuple[float, float], max_heading_deg: float):
    """``(in_band, facing)``: whether points lie strictly inside the distance ``band`` of the
    robot base and within ``max_heading_deg`` of its heading.

    Args:
        xy: ``(..., 2)`` points.
        robot_xy, robot_yaw: ``(..., 2)`` and ``(...)``, broadcasting against them.
    """
    xp = array_module(xy)
    rel = xy - robot_xy
    d = xp.hypot(rel[..., 0], rel[..., 1])
    facing = heading_error(rel, robot_yaw) <= math.radians(max_heading_deg)
    return (d > band[0]) & (d < band[1]), facing


def nonzero(mask) -> tuple:
    """The indices of a mask's True entries, one array per dim (numpy and torch alike)."""
    return np.nonzero(mask) if array_module(mask) is np else mask.nonzero(as_tuple=True)


def first_true(mask):
    """``(first, any)`` along the last dim of a bool mask: the index of its first True (0 where
    none) and whether there is one."""
    xp = array_module(mask)
    as_int = mask if xp is np else mask.to(xp.uint8)  # numpy's argmax takes bools
    return as_int.argmax(-1), mask.any(-1)


def candidates_fit(
    xy, yaw, foot, foot_normals, radius, region, placed, clearance, reach=None,
    shift=None,
):
    """Which candidate poses of one object meet every rule, in each env; the one test both
    placements run.

    Args:
        xy, yaw: ``(b, c, 2)`` and ``(b, c)``: c candidates in each of b envs.
        foot, foot_normals: ``(m, 2)`` the object's footprint about its origin (CCW) and its
            :func:`inward_normals`.
        radius: the footprint's bounding radius about its origin.
        region: ``(normals (b, e, 2), offsets (b, e))`` the support's top, shrunk by the hull
            margin (:func:`half_planes`); None on the floor, which has no edge.
        placed: ``(polys (b, o, k, 2), normals (b, o, k, 2), origins (b, o, 2), radii (o,))``:
            the footprints to keep clear of (padded edges have zero normals) with their
            bounding circles.
        clearance: the minimum gap between footprints: a float, or ``(o,)`` one per placed
            footprint (``Standing.gaps``).
        reach: None, or ``(robot_xy (b, 2), robot_yaw (b,), band, max_heading_deg)`` for a
            manipulated object (:func:`within_reach`).
        shift: None, or ``(dx, dy)`` in the robot's frame: where a move task takes the object
            from each candidate (needs ``reach``); the footprint there must be inside the
            region, its centre within reach and the footprint clear of ``placed``.

    Returns:
        ``dict`` of ``(b, c)`` bool masks: ``inside`` (with a region) and, with ``reach``,
        ``in_band`` and ``facing`` for every candidate, with ``shift`` ``destination``;
        ``clear`` for those meeting the others (True where they do not: the separating-axis
        test runs only there, and only where bounding circles meet; the destination's
        clearance likewise, in ``destination``).
    """
    poly = rotate(foot, yaw) + xy[..., None, :]  # (b, c, m, 2)
    masks = {}
    ok = None  # every rule so far (None: no rule yet)
    if region is not None:
        masks["inside"] = ok = inside(poly, region[0][:, None], region[1][:, None])
    if reach is not None:
        robot_xy, robot_yaw, band, heading = reach
        masks["in_band"], masks["facing"] = within_reach(
            xy, robot_xy[:, None], robot_yaw[:, None], band, heading
        )
        reached = masks["in_band"] & masks["facing"]
        ok = reached if ok is None else ok & reached
        if shift is not None:
            offset = move_offset(shift, robot_yaw)
            dest = xy + offset
            band_ok, facing_ok = within_reach(
                dest, robot_xy[:, None], robot_yaw[:, None], band, heading
            )
            there = band_ok & facing_ok
            if region is not None:
                there = there & inside(poly + offset[..., None, :], region[0][:, None],
                                       region[1][:, None])  # fmt: skip
            masks["destination"] = there
            ok = ok & there
    masks["clear"] = _clear(xy, yaw, poly, foot_normals, radius, placed, clearance, ok)
    if shift is not None:  # the destination's footprint, where every other rule holds
        there = masks["clear"] & ok
        masks["destination"] = masks["destination"] & _clear(
            xy + offset, yaw, poly + offset[..., None, :], foot_normals, radius, placed,
            clearance, there,
        )  # fmt: skip
    return masks


def move_offset(shift, robot_yaw):
    """``(b, 1, 2)``: where a move task takes an object from its start, in the world, for the
    robot yaws ``(b,)`` (``shift``: ``(dx, dy)`` in the robot's frame, ``Task.shift``)."""
    xp = array_module(robot_yaw)
    vec = (np.asarray([shift], dtype=robot_yaw.dtype) if xp is np else
           xp.as_tensor([shift], dtype=robot_yaw.dtype, device=robot_yaw.device))  # fmt: skip
    return rotate(vec, robot_yaw)


def _clear(xy, yaw, poly, foot_normals, radius, placed, clearance, where=None):
    """``(b, c)``: whether each candidate footprint ``poly (b, c, m, 2)`` centred at ``xy`` is
    no closer than ``clearance`` (m, or ``(o,)``: one per placed footprint) to every ``placed``
    footprint; tested only ``where`` (True elsewhere), and only against footprints whose
    bounding circles it meets."""
    xp = array_module(xy)
    polys, normals, origins, radii = placed
    rel = xy[:, :, None] - origins[:, None]  # (b, c, o, 2)
    near = xp.hypot(rel[..., 0], rel[..., 1]) < radius + radii + clearance
    e, c, o = nonzero(near if where is None else near & where[..., None])
    clear = all_true(yaw)
    if len(e):
        pair_normals = rotate(foot_normals, yaw[e, c])
        gap = clearance if np.ndim(clearance) == 0 else clearance[o][:, None]
        hit = overlap(poly[e, c], polys[e, o], gap, pair_normals, normals[e, o])
        clear[e[hit], c[hit]] = False
    return clear
