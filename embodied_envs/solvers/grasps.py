"""Grasp synthesis from an asset's collision geometry: antipodal, collision-free, ranked.

:func:`asset_grasps` computes an asset's grasps once, in the object's own frame, and caches them
by the asset's file versions; :func:`posed_grasps` poses them for one episode and keeps those the
gripper can take there. A grasp is a parallel-jaw grasp of the Panda, described in ManiSkill's
``panda_hand_tcp`` frame (``build_grasp_pose``: z approaches, y closes):

1. **Antipodal contacts.** Points are sampled on the outer surface of the collision parts (a
   point inside another part is not on the surface); a ray from each goes into the material
   along the inward normal and leaves it at the first outer surface point. The pair is kept
   when the exit normal lies within the friction cone (``GraspConfig.cone_deg``) of the
   closing line, and the width fits the opening with margin. The grasp centre is the middle
   of the pair: inside the material.
2. **Approaches.** Each contact pair is approached from ``approaches`` directions around its
   closing line (all perpendicular to it); posing keeps those within ``max_tilt_deg`` of
   straight down (side grasps where top-down cannot reach, e.g. a tall bottle or a handle).
3. **Collision-free gripper.** Boxes matching the Panda's open fingers and palm
   (:class:`GripperModel`), swept back along the approach to the pre-grasp, must hold no point
   of the object; posed, none of the table top nor of the other objects (their surface points;
   grasps clear of them by ``wide_margin`` first: the arm deviates by a centimetre or two).
4. **Ranking** (lower is better): grasps whose gripper clears the object by ``wide_margin``
   before the others (the arm tracks its targets within millimetres), then the grasp centre's
   distance from the centre of mass (a grip near it holds against gravity), the approach's tilt
   from straight down, and the contact width's distance from the middle of the opening.

5. **Annotations.** Grasps EmbodiedGen's ``affordance-cli`` wrote for the asset
   (``affordance_annot.json``, read by ``layout/affordance.py``) that pass the checks of 1 and 3
   rank ahead of the synthesised ones, by their confidence (``solvers/annotated.py``).

The same asset gives the same ranked list (the sampling is seeded by the asset's content).
"""

from __future__ import annotations

import hashlib

import numpy as np

from embodied_envs.layout.affordance import annotation_path
from embodied_envs.layout.assets import ASSET_FILES, AssetSpec, FileVersion, asset_geometry
from embodied_envs.solvers.annotated import with_annotations
from embodied_envs.solvers.grasp_types import GraspConfig, GraspError, Grasps
from embodied_envs.solvers.gripper import (
    GripperModel,
    box_clearance,
    box_corners,
    pair_clearance,
    point_clearance,
    tcp_axes,
)
from embodied_envs.solvers.store import cached, result_name


def _seed(spec: AssetSpec) -> int:
    """A seed from the collision mesh's bytes: the same asset samples the same points."""
    return int.from_bytes(hashlib.sha256(spec.collision.path.read_bytes()).digest()[:8], "little")


def hull_points(spec: AssetSpec, n: int) -> np.ndarray:
    """About ``n`` points on the convex hulls of an asset's collision parts, in its own frame
    (the obstacle cloud the planner keeps clear of); sampled once per file version, seeded by
    the asset's content, and kept between runs (``store.py``)."""

    def sample() -> np.ndarray:
        import trimesh  # only where clouds are sampled (the CLI starts without it)

        parts = asset_geometry(spec).parts
        rng = np.random.default_rng(_seed(spec))
        per = max(n // max(len(parts), 1), 50)
        points = []
        for verts in parts:
            with np.errstate(all="ignore"):  # thin parts have near-zero volume; sampling is fine
                hull = trimesh.Trimesh(vertices=verts).convex_hull
                pts, _ = trimesh.sample.sample_surface(hull, per, seed=int(rng.integers(2**31)))
            points.append(pts)
        return np.concatenate(points)

    key = ("hull points", FileVersion.of(spec.collision.path), spec.collision, n)
    mesh = spec.collision
    settings = (mesh.path.suffix.lower(), mesh.xyz, mesh.rpy, mesh.scale, n)
    name = lambda: result_name("hull-points", (mesh.path,), settings, STORED_BY)  # noqa: E731
    return ASSET_FILES.get(key, lambda: cached(name(), sample, np.ndarray))


def object_points(spec: AssetSpec, n: int) -> np.ndarray:
    """An asset's collision vertices and about ``n`` points on its parts' hulls
    (:func:`hull_points`), in its own frame: its extremes exactly and its surface between them
    (the part of an object between a hand's jaws, ``GripperModel.between``)."""
    return np.concatenate([asset_geometry(spec).vertices, hull_points(spec, n)])


def _outer_surface(parts, n: int, rng: np.random.Generator):
    """Points and outward normals on the union of convex parts, none inside another part."""
    import trimesh  # only where grasps are computed (the CLI starts without it)

    hulls = [trimesh.Trimesh(vertices=p).convex_hull for p in parts]
    areas = np.array([h.area for h in hulls])
    counts = np.maximum(1, np.round(n * 2 * areas / areas.sum()).astype(int))
    points, normals = [], []
    for k, (hull, m) in enumerate(zip(hulls, counts, strict=True)):
        pts, faces = trimesh.sample.sample_surface(hull, int(m), seed=int(rng.integers(2**31)))
        nrm = hull.face_normals[faces]
        outside = np.ones(len(pts), bool)
        for j, other in enumerate(hulls):
            if j != k:
                outside &= ~_inside(other, pts, 1e-4)
        points.append(pts[outside])
        normals.append(nrm[outside])
    points, normals = np.concatenate(points), np.concatenate(normals)
    keep = rng.permutation(len(points))[:n]
    return points[keep], normals[keep], hulls


def _inside(hull, points: np.ndarray, eps: float) -> np.ndarray:
    """Points strictly inside a convex hull (deeper than ``eps``)."""
    normals, origins = hull.face_normals, hull.triangles[:, 0]
    d = np.einsum("pfk,fk->pf", points[:, None, :] - origins[None], normals)
    return (d < -eps).all(1)


def _exit_points(hulls, points: np.ndarray, normals: np.ndarray):
    """For each surface point, where a ray into the material (along the inward normal) leaves
    the union of the convex parts, and the outward normal there; NaN where it never enters.

    Each part's interval along the ray comes from its face planes; the exit is the end of the
    run of overlapping intervals that starts at the point.
    """
    d = -normals
    n = len(points)
    t_in = np.full((len(hulls), n), np.inf)
    t_out = np.full((len(hulls), n), -np.inf)
    exit_normal = np.zeros((len(hulls), n, 3))
    for j, hull in enumerate(hulls):
        fn, c = hull.face_normals, np.einsum("fk,fk->f", hull.face_normals, hull.triangles[:, 0])
        along = d @ fn.T  # (n, f)
        gap = c[None] - points @ fn.T  # >= 0 inside each plane
        with np.errstate(divide="ignore", invalid="ignore"):
            t = gap / along
        leave = np.where(along > 1e-12, t, np.inf)
        enter = np.where(along < -1e-12, t, -np.inf)
        blocked = ((np.abs(along) <= 1e-12) & (gap < 0)).any(1)
        lo, hi = enter.max(1), leave.min(1)
        valid = (lo < hi) & ~blocked
        t_in[j] = np.where(valid, lo, np.inf)
        t_out[j] = np.where(valid, hi, -np.inf)
        exit_normal[j] = fn[leave.argmin(1)]
    end = np.zeros(n)
    started = np.zeros(n, bool)
    for _ in range(len(hulls)):  # grow the run of overlapping intervals from t = 0
        joined = (t_in <= end[None] + 1e-6) & (t_out > end[None] + 1e-6)
        grows = joined.any(0)
        if not grows.any():
            break
        started |= grows
        end = np.where(grows, np.where(joined, t_out, -np.inf).max(0), end)
    out = np.full_like(points, np.nan)
    out_n = np.full_like(points, np.nan)
    ok = started & (end > 1e-3)
    last = np.argmax(np.where(np.isclose(t_out, end[None]), 1, 0), axis=0)
    out[ok] = points[ok] + end[ok, None] * d[ok]
    out_n[ok] = exit_normal[last[ok], np.flatnonzero(ok)]
    return out, out_n


def _spans(points: np.ndarray, exits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pair's unit closing line (from the point to its exit) and width; zero where the
    ray found no exit (NaN: its width fits nothing)."""
    span = exits - points
    width = np.linalg.norm(span, axis=1)
    closing = np.nan_to_num(span / np.maximum(width, 1e-9)[:, None])
    return closing, width


TILTS = (1 / 3, 2 / 3, 1.0)  # parts of the tilted cone the tilted rays lean at
AZIMUTHS = 12  # and the directions around each inward normal they lean toward


def _tilted_rays(points: np.ndarray, normals: np.ndarray, cone: float):
    """Rays into the material from each surface point, leaning from its inward normal by
    ``TILTS`` of ``cone`` (rad) toward ``AZIMUTHS`` directions: ``(points, rays)``, each point
    repeated per ray."""
    inward = -normals
    ref = np.where(np.abs(inward[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(inward, ref)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(inward, u)
    az = np.arange(AZIMUTHS) * 2 * np.pi / AZIMUTHS
    lean = np.asarray(TILTS) * cone
    a, b = np.meshgrid(lean, az, indexing="ij")
    a, b = a.ravel(), b.ravel()  # (k,)
    rays = (np.cos(a)[None, :, None] * inward[:, None]
            + (np.sin(a) * np.cos(b))[None, :, None] * u[:, None]
            + (np.sin(a) * np.sin(b))[None, :, None] * v[:, None])  # fmt: skip
    return np.repeat(points, len(a), 0), rays.reshape(-1, 3)


def _frames(closing: np.ndarray, count: int) -> np.ndarray:
    """``count`` unit approach directions perpendicular to each closing line ``(n, 3)``:
    ``(n, count, 3)``, starting from the one nearest to -z of the object's frame."""
    down = np.array([0.0, 0.0, -1.0])
    ref = down - (closing @ down)[:, None] * closing
    flat = np.linalg.norm(ref, axis=1) < 1e-6  # closing vertical: any perpendicular
    ref[flat] = np.cross(closing[flat], [1.0, 0.0, 0.0])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    side = np.cross(closing, ref)
    angles = np.arange(count) * 2 * np.pi / count
    return (
        np.cos(angles)[None, :, None] * ref[:, None] + np.sin(angles)[None, :, None] * side[:, None]
    )


SAMPLE_FRACTIONS = (36, 6, 1)  # grasps are checked against these fractions of the object's
# points in turn (nested samples)
LIPSCHITZ_SLACK = 1e-5  # m, float32 rounding allowed for in the bound on a point's clearance


def _compute(spec: AssetSpec, cfg: GraspConfig, gripper: GripperModel) -> Grasps:
    import trimesh  # only where grasps are computed

    geom = asset_geometry(spec)
    rng = np.random.default_rng(_seed(spec))
    points, normals, hulls = _outer_surface(geom.parts, cfg.surface_samples, rng)
    mesh = trimesh.util.concatenate(hulls)
    fits = lambda width: (width >= cfg.min_width) & (width <= gripper.opening - cfg.width_margin)  # noqa: E731
    exits, exit_n = _exit_points(hulls, points, normals)
    closing, width = _spans(points, exits)
    ok = fits(width) & (np.einsum("ij,ij->i", exit_n, closing) >= np.cos(np.radians(cfg.cone_deg)))
    if (cfg.tilted_too or not ok.any()) and cfg.tilted_cone_deg > cfg.cone_deg:
        t_points, rays = _tilted_rays(points, normals, np.radians(cfg.tilted_cone_deg))
        t_exits, t_exit_n = _exit_points(hulls, t_points, -rays)
        t_closing, t_width = _spans(t_points, t_exits)
        cos_cone = np.cos(np.radians(cfg.tilted_cone_deg))
        t_ok = fits(t_width) & (np.einsum("ij,ij->i", t_exit_n, t_closing) >= cos_cone)
        keep = ok if cfg.tilted_too else np.zeros_like(ok)  # the straight pairs first
        points, exits, closing, width = (
            np.concatenate([a[keep], b])
            for a, b in ((points, t_points), (exits, t_exits), (closing, t_closing),
                         (width, t_width))
        )  # fmt: skip
        ok = np.concatenate([np.ones(int(keep.sum()), bool), t_ok])
    vols = np.array([h.volume for h in hulls])
    com = (np.array([h.center_mass for h in hulls]) * vols[:, None]).sum(0) / vols.sum()
    if not ok.any():
        raise GraspError(
            f"{spec.urdf_path}: no antipodal contact pair of its collision parts fits the "
            f"gripper's {gripper.opening * 100:.0f} cm opening (with {cfg.width_margin * 100:.1f}"
            " cm margin). Fix: scale the asset so that some part of it is narrower."
        )
    centre = (points[ok] + exits[ok]) / 2
    closing, width = closing[ok], width[ok]
    pick = np.sort(rng.permutation(len(centre))[: cfg.max_pairs])  # spread over the surface
    centre, closing, width = centre[pick], closing[pick], width[pick]
    approach = _frames(closing, cfg.approaches)  # (n, a, 3)
    n, a = approach.shape[:2]
    centre = np.repeat(centre, a, 0)
    closing = np.repeat(closing, a, 0)
    width = np.repeat(width, a, 0)
    approach = approach.reshape(-1, 3)
    cloud = trimesh.sample.sample_surface(mesh, cfg.check_points, seed=int(rng.integers(2**31)))[0]
    opening = np.minimum(gripper.opening, width + 2 * cfg.preshape)
    boxes = gripper.boxes(cfg.sweep, opening)  # (n, 3, 2, 3)
    free = np.zeros(len(centre), bool)
    roomy = np.zeros(len(centre), bool)  # clear by the wider margin too
    # nested seeded samples of the cloud in turn, the smallest with every (grasp, point) pair.
    # A point's clearance moves no more than the point does, so a point is at least (the
    # clearance of its nearest point in the sample before - their distance) clear: only the
    # pairs that bound leaves within wide_margin are measured, and a grasp a sample already
    # hits is dropped (the same results as measuring every pair; most pairs skipped)
    levels = [cloud[: max(1, len(cloud) // f)] for f in SAMPLE_FRACTIONS]
    links = []  # per sample after the first: each point's nearest point before, and distance
    for before, now in zip(levels[:-1], levels[1:], strict=True):
        apart = np.linalg.norm(now[:, None] - before[None], axis=-1)
        nearest = apart.argmin(1)
        links.append((nearest, apart[np.arange(len(now)), nearest].astype(np.float32)))
    for s in range(0, len(centre), 256):
        part = np.arange(s, min(s + 256, len(centre)))
        rot = tcp_axes(closing[part], approach[part])
        lower = point_clearance(levels[0], centre[part], closing[part], approach[part], boxes[part])
        for points, (nearest, apart) in zip(levels[1:], links, strict=True):
            keep = lower.min(1) > cfg.margin
            part, rot, lower = part[keep], rot[keep], lower[keep]
            lower = lower[:, nearest] - apart  # lower bounds on each point's clearance
            g, k = np.nonzero(lower <= cfg.wide_margin + LIPSCHITZ_SLACK)
            lower[g, k] = pair_clearance(points, centre[part], rot, boxes[part], g, k)
        # exact up to wide_margin: a point nearer than that was measured
        gap = lower.min(1)
        free[part], roomy[part] = gap > cfg.margin, gap > cfg.wide_margin
    if not free.any():
        raise GraspError(
            f"{spec.urdf_path}: every antipodal grasp of its collision parts puts the gripper's "
            "fingers or palm into the object. Fix: check the collision mesh (a closed, "
            "gripper-sized part is needed)."
        )
    centre, closing, approach = centre[free], closing[free], approach[free]
    width, opening = width[free], opening[free]
    score = (
        np.linalg.norm(centre - com, axis=1) / 0.05
        + np.abs(width - gripper.opening / 2) / 0.08
        + 2.0 * ~roomy[free]  # a grasp the arm's error could bump comes after the roomy ones
    )
    order = np.argsort(score, kind="stable")
    planes = tuple(
        np.concatenate([h.face_normals, -np.einsum("fk,fk->f", h.face_normals,
                                                   h.triangles[:, 0])[:, None]], 1)
        for h in hulls
    )  # fmt: skip
    return Grasps(
        centre[order], closing[order], approach[order], width[order], opening[order],
        score[order], com, cloud, planes,
    )  # fmt: skip


def asset_grasps(
    spec: AssetSpec, cfg: GraspConfig | None = None, gripper: GripperModel | None = None
) -> Grasps:
    """The grasps of an asset in its own frame, best first; computed once per file version
    (``ASSET_FILES``) and configuration, and kept between runs (``store.py``).

    Raises:
        GraspError: naming the asset, when no grasp fits the gripper.
    """
    cfg, gripper = cfg or GraspConfig(), gripper or GripperModel()
    annot = annotation_path(spec.urdf_path)
    version = FileVersion.of(annot) if annot else None
    key = ("grasps", FileVersion.of(spec.collision.path), version, spec.collision, cfg, gripper)
    mesh = spec.collision
    settings = (mesh.path.suffix.lower(), mesh.xyz, mesh.rpy, mesh.scale, cfg, gripper)

    def compute() -> Grasps:
        name = result_name("grasps", (mesh.path, annot), settings, STORED_BY)
        return cached(name, lambda: with_annotations(_compute(spec, cfg, gripper), annot, cfg,
                                                     gripper), Grasps)  # fmt: skip

    return ASSET_FILES.get(key, compute)


# the modules whose code determines an asset's grasps (store.py names them by their source)
STORED_BY = (__name__, "embodied_envs.solvers.grasp_types", "embodied_envs.solvers.gripper",
             "embodied_envs.solvers.annotated", "embodied_envs.solvers.store",
             "embodied_envs.layout.affordance", "embodied_envs.layout.assets",
             "embodied_envs.layout.collision")  # fmt: skip


ROUND_BULGE = 0.002  # m: a body this much narrower at its top than at its widest section
# above the footprint grasp's height is round there (a ball, a cylinder on its side)
WIDEST_BAND = 0.0005  # m: sections this close to the widest are as wide (facets)


def widest_height(
    vertices: np.ndarray, closing: np.ndarray, z: float, top: float, lowest: float | None = None
) -> float:
    """Where a top-down grasp closing along ``closing`` (world, horizontal) planned at height
    ``z`` should close: for a body that narrows towards ``top`` by ``ROUND_BULGE`` (the
    vertices' convex hull, sliced every millimetre from its bottom), the middle of its widest
    band of sections when that lies above ``z`` (fingers closing below the equator of a ball
    or of a cylinder on its side squeeze it up and out), or below ``z`` down to ``lowest``
    for a body within ``ROUND_BULGE`` of that width over less than half its height (above
    the equator fingers squeeze it down and out: the Koch, which grasps 5 mm under the top,
    held a 2.9 cm ball 4 times in 6 so, 6 in 6 at the equator); else ``z`` (a box, a can, a
    bottle's neck, a cone)."""
    from scipy.spatial import ConvexHull, QhullError  # only where grasps are posed

    if top <= (z if lowest is None else lowest):
        return z
    points = np.asarray(vertices, dtype=np.float64)
    # triangles: any triangulation of the hull's faces gives the same sections' extremes (they
    # lie on the hull's edges)
    try:
        faces = ConvexHull(points, qhull_options="Qt").simplices
    except QhullError:  # flat or degenerate points: joggled, as trimesh retries
        faces = ConvexHull(points, qhull_options="QJ").simplices
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]],
                                              faces[:, [2, 0]]]), 1), axis=0)  # fmt: skip
    a, b = points[edges].transpose(1, 0, 2)  # (e, 3) each
    bottom = points[:, 2].min()
    heights = np.linspace(bottom, top, max(2, int(np.ceil((top - bottom) / 0.001)) + 1))
    lo, hi = np.minimum(a[:, 2], b[:, 2]), np.maximum(a[:, 2], b[:, 2])
    # every slice at once (heights x edges): its corners, where edges cross its plane
    h = heights[:, None]
    cross = (lo <= h) & (hi >= h) & (hi > lo)
    rise = np.where(hi > lo, b[:, 2] - a[:, 2], 1.0)  # edges in no slice: any nonzero
    along = a @ closing + (h - a[:, 2]) / rise * ((b - a) @ closing)
    most = np.where(cross, along, -np.inf).max(1)
    widths = np.where(cross.any(1), most - np.where(cross, along, np.inf).min(1), 0.0)
    if widths[-1] >= widths.max() - ROUND_BULGE:
        return z  # as wide at the top: no bulge
    band = heights[widths >= widths.max() - WIDEST_BAND]  # contiguous: a convex body's
    middle = float((band.min() + band.max()) / 2)  # section widths are concave in height
    if middle <= z:  # lower only to a bulge: as wide over less than half the height (a
        # ball, a lying cylinder or hex prism; not a bottle's body below its neck)
        near = heights[widths >= widths.max() - ROUND_BULGE]
        bulge = near.max() - near.min() < (top - bottom) / 2
        return max(middle, lowest) if lowest is not None and bulge else z
    return min(middle, top)


def grasp_is_valid(
    grasps: Grasps,
    centre: np.ndarray,
    closing: np.ndarray,
    approach: np.ndarray,
    cfg: GraspConfig | None = None,
    gripper: GripperModel | None = None,
) -> bool:
    """Whether a grasp given in the object's frame (fully open fingers) passes the checks the
    synthesised ones pass: its centre inside the material, and no object point in the swept
    gripper boxes."""
    cfg, gripper = cfg or GraspConfig(), gripper or GripperModel()
    inside = any((p[:, :3] @ centre + p[:, 3] < 0).all() for p in grasps.planes)
    gap = box_clearance(grasps.points, centre[None], closing[None], approach[None],
                        gripper.boxes(cfg.sweep)[None])  # fmt: skip
    return bool(inside and gap[0] > cfg.margin)


def posed_grasps(
    grasps: Grasps,
    object_to_world: np.ndarray,
    support_z: float,
    obstacles: np.ndarray | None = None,
    cfg: GraspConfig | None = None,
    gripper: GripperModel | None = None,
    limit: int = 8,
    with_index: bool = False,
    keep: np.ndarray | None = None,
    roomy_first: bool = True,
) -> list[tuple]:
    """The grasps the gripper can take in this episode, best first, as world
    ``(centre, closing, approach, opening)``: approach within ``max_tilt_deg`` of straight down, the
    swept gripper above the support surface and clear of ``obstacles`` (world points) by
    ``obstacle_margin``, ranked by the pre-posing score plus the tilt, those clear of the
    obstacles by ``wide_margin`` first (among the ``posed_scan`` best, or until ``limit`` are
    clear). At most ``limit``; an empty list when none. ``with_index``: each tuple ends with
    the grasp's index in ``grasps``. ``keep``: ``(n,)`` bool, the grasps considered (all when
    None). ``roomy_first=False``: the clear grasps in their rank alone, which a centimetre's
    move of the object leaves in place (``SolverConfig.consistent``)."""
    cfg, gripper = cfg or GraspConfig(), gripper or GripperModel()
    rot, t = object_to_world[:3, :3], object_to_world[:3, 3]
    centre = grasps.centre @ rot.T + t
    closing = grasps.closing @ rot.T
    approach = grasps.approach @ rot.T
    tilt = np.arccos(np.clip(-approach[:, 2], -1.0, 1.0))
    idx = np.flatnonzero((tilt <= np.radians(cfg.max_tilt_deg)) & (True if keep is None else keep))
    idx = idx[np.argsort(grasps.score[idx] + tilt[idx] / np.radians(45.0), kind="stable")]
    boxes = gripper.boxes(cfg.sweep, grasps.opening)  # (n, 3, 2, 3)
    if obstacles is not None and len(obstacles):  # those a gripper box can reach
        reach = np.abs(boxes).max() * np.sqrt(3) + np.linalg.norm(grasps.points, axis=1).max()
        obstacles = obstacles[np.linalg.norm(obstacles - t, axis=1) <= reach]
    roomy, tight = [], []
    for s in range(0, len(idx), 64):  # best first, until ``limit`` are roomy (or, past the
        part = idx[s : s + 64]  # ``posed_scan`` best, until ``limit`` are clear)
        clear, wide = posed_clearance(
            centre[part], closing[part], approach[part], boxes[part], support_z, obstacles, cfg
        )
        roomy.extend(part[wide if roomy_first else clear])
        tight.extend(part[clear & ~wide] if roomy_first else [])
        if len(roomy) >= limit or (s + 64 >= cfg.posed_scan and len(roomy) + len(tight) >= limit):
            break
    best = (roomy + tight)[:limit]
    tail = (lambda i: (int(i),)) if with_index else (lambda i: ())
    return [(centre[i], closing[i], approach[i], float(grasps.opening[i]), *tail(i)) for i in best]


def posed_clearance(
    centre: np.ndarray,
    closing: np.ndarray,
    approach: np.ndarray,
    boxes: np.ndarray,
    support_z: float,
    obstacles: np.ndarray | None,
    cfg: GraspConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """``(clear, roomy)`` per posed grasp (world ``(n, 3)`` arrays, gripper ``boxes (n, 3, 2,
    3)``): clear when the swept boxes stay ``clearance`` above the support surface and hold no
    obstacle point (world) within ``obstacle_margin``; roomy when clear and none is within
    ``wide_margin`` either."""
    world = box_corners(centre, tcp_axes(closing, approach), boxes)
    clear = world[..., 2].min(1) >= support_z + cfg.clearance
    if obstacles is None or not len(obstacles) or not clear.any():
        return clear, clear
    rows = np.flatnonzero(clear)  # only grasps clear of the table meet the obstacles
    gap = np.full(len(centre), np.inf, dtype=np.float32)
    gap[rows] = box_clearance(
        obstacles, centre[rows], closing[rows], approach[rows], boxes[rows],
        max(cfg.wide_margin, cfg.obstacle_margin),
    )  # fmt: skip
    clear &= gap > cfg.obstacle_margin
    return clear, clear & (gap > cfg.wide_margin)
