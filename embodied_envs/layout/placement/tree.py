"""The support tree, walked once for both placements.

Objects stand on the context (the table) or on other objects (relations ``ON``, ``IN``,
``INSIDE``). :func:`support_tree` walks that tree breadth first from the context, larger
footprints first, and gives each object what both placements need: its parent, its asset's
footprint, bottom and top, whether it is manipulated, and which placed footprints it keeps
clear of. The per-configuration placer (``configuration.place``) and the per-episode sampler
(``episode.EpisodeSampler``) place the objects in this order by the same rules.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from embodied_envs.layout.errors import PlacementError
from embodied_envs.layout.placement.geometry import (
    AssetKey,
    Top,
    asset_key,
    key_footprint,
    key_geometry,
    key_top,
    polygon_area,
)
from embodied_envs.layout.placement.limits import PlacementLimits
from embodied_envs.layout.schema import LayoutInfo

SUPPORT_RELATIONS = ("ON", "IN", "INSIDE")


@dataclass(frozen=True)
class Standing:
    """One object standing on the context or on another object.

    Attributes:
        node, parent: the object and what it stands on.
        key: its asset's key (``geometry.asset_key``).
        footprint: ``(m, 2)`` its convex footprint in its own frame (CCW).
        min_z: its lowest collision point in its own frame.
        top: its top in its own frame, shrunk by the hull margin.
        supports: whether objects stand on it (then its shrunk top exists).
        manipulated: whether the robot is to grasp it (it stands within reach).
        shift: for a mover of a ``move`` task, its destination relative to its start in the
            robot's frame (``Task.shift``), kept on the top and within reach; else None.
        avoid: the obstacles it keeps clear of, as indices into ``[robot base, items...]``:
            the robot base (0) and the objects placed before it (``1 + their index``), less
            those it stands on (its parent's chain down to the context).
        avoid_destinations: the movers of a ``move`` task among ``avoid`` (the same indices):
            it keeps clear of their destination footprints too (``rules``).
        avoid_rest: the links of the arm at rest it keeps clear of (rows of
            ``PlacementLimits.rest_arm``: those its top comes near, ``rest_links``).
        gaps: the least gap (m) to each of ``avoid + avoid_destinations`` (``PlacementLimits.gap``:
            wider beside the task's movers), then ``rest_clearance`` to each of ``avoid_rest``.
    """

    node: str
    parent: str
    key: AssetKey
    footprint: np.ndarray
    min_z: float
    top: Top
    supports: bool
    manipulated: bool
    avoid: tuple[int, ...]
    shift: tuple[float, float] | None = None
    avoid_destinations: tuple[int, ...] = ()
    avoid_rest: tuple[int, ...] = ()
    gaps: tuple[float, ...] = ()


@dataclass(frozen=True)
class SupportTree:
    """A layout's objects in placement order (:func:`support_tree`).

    Attributes:
        context: the context node (the table).
        keys: every object node's asset key.
        context_top: the context's top in its own frame, shrunk by the hull margin (never
            None: the robot stands on its shrunk boundary).
        items: the objects standing on the context or on other objects, in placement order.
    """

    context: str
    keys: dict[str, AssetKey]
    context_top: Top
    items: tuple[Standing, ...]


def support_order(layout: LayoutInfo, keys: dict[str, AssetKey] | None = None):
    """``(node, parent)`` of every object standing on the context or on another object, in
    placement order: breadth first from the context, larger footprints first."""
    keys = keys if keys is not None else {}
    order: list[tuple[str, str]] = []
    queue = [layout.context]
    while queue:
        parent = queue.pop(0)
        kids = [
            c for c, r in layout.children(parent) if r in SUPPORT_RELATIONS and c != layout.robot
        ]
        for kid in kids:
            if kid not in keys:
                keys[kid] = asset_key(layout, kid)
        kids.sort(key=lambda n: -polygon_area(key_footprint(keys[n])))
        order += [(kid, parent) for kid in kids]
        queue += kids
    return order


def support_tree(layout: LayoutInfo, limits: PlacementLimits) -> SupportTree:
    """Walk a layout's support tree once: its objects in placement order with their geometry.

    Raises:
        PlacementError: a top that something stands on (the context's, where the robot
            stands, or an object's) vanishes when shrunk by the hull margin.
    """
    keys = {n: asset_key(layout, n) for n in layout.object_nodes()}
    ctx = layout.context
    order = support_order(layout, keys)
    parents = {parent for _, parent in order}
    band, margin = limits.top_band, limits.hull_margin
    context_top = key_top(keys[ctx], band, margin)
    ancestors = {ctx: {ctx}}
    heights = {ctx: 0.0}  # each support's top above the table top (objects stand on their tops)
    obstacles = [layout.robot]  # the robot base, then the objects in order
    items = []
    for node, parent in order:
        ancestors[node] = ancestors[parent] | {node}
        avoid = tuple(i for i, o in enumerate(obstacles) if o not in ancestors[parent])
        moving = tuple(i for i in avoid if i and items[i - 1].shift is not None)
        geom = key_geometry(keys[node])
        heights[node] = heights[parent] + geom.max_z - geom.min_z
        rest = limits.rest_links(heights[node])
        gaps = tuple(limits.gap(node, obstacles[i] if i else None, layout.task.objects)
                     for i in avoid + moving) + (limits.rest_clearance,) * len(rest)  # fmt: skip
        obstacles.append(node)
        items.append(
            Standing(
                node=node,
                parent=parent,
                key=keys[node],
                footprint=key_footprint(keys[node]),
                min_z=geom.min_z,
                top=key_top(keys[node], band, margin),
                supports=node in parents,
                manipulated=node in layout.reach_nodes,
                avoid=avoid,
                shift=layout.task.shift() if node in layout.task.objects else None,
                avoid_destinations=moving,
                avoid_rest=rest,
                gaps=gaps,
            )
        )
    first_child = {ctx: layout.robot}  # the first to stand on each support
    for node, parent in order:
        first_child.setdefault(parent, node)
    tops = [(ctx, context_top)] + [(it.node, it.top) for it in items if it.supports]
    for support, top in tops:
        if top.shrunk is None:
            raise PlacementError(
                first_child[support],
                "a top to stand on",
                0,
                f'the top of "{support}" is smaller than twice placement_limits.hull_margin '
                f"({margin} m)",
                str(layout.source or ""),
            )
    return SupportTree(ctx, keys, context_top, tuple(items))
