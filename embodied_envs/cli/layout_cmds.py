"""``embodied-envs layout generate | validate | preview``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
from PIL import Image, ImageDraw
from tqdm import tqdm

from embodied_envs.cli.args import image_side, positive_int, seed_int, writable_dir
from embodied_envs.config import resolve_robot
from embodied_envs.layout import LayoutError, LayoutInfo, PlacementError, load_layout
from embodied_envs.layout.affordance import AffordanceError, annotation_path, read_annotation
from embodied_envs.layout.collision import DECOMPOSED, obj_objects
from embodied_envs.layout.placement import (
    PlacementLimits,
    node_footprint,
    node_geometry,
    place,
    square,
    top_surface,
    world_vertices,
)
from embodied_envs.layout.placement.rules import rotate
from embodied_envs.layout.pools import asset_pools
from embodied_envs.layout.sets import LayoutSet, layout_files
from embodied_envs.paths import atomic_output
from embodied_envs.robots import ROBOTS
from embodied_envs.splat import SplatFileError, check_ply
from embodied_envs.workers import run


def add_parser(sub) -> None:
    p = sub.add_parser("layout", help="generate, validate and preview layouts")
    lsub = p.add_subparsers(dest="layout_cmd", required=True)

    g = lsub.add_parser("generate", help="write N placed variants of a layout")
    g.add_argument("layout", type=Path)
    g.add_argument("--num", type=positive_int, required=True, help="number of variants")
    g.add_argument("--seed", type=seed_int, default=0, help="variant i uses seed + i")
    g.add_argument("--out", type=Path, required=True, help="output folder (created)")
    g.add_argument("--workers", type=positive_int, default=1, help="parallel processes")
    g.set_defaults(func=cmd_generate)

    v = lsub.add_parser("validate", help="check layouts and their asset folders")
    v.add_argument(
        "layouts", nargs="+", help="layout files, folders of them or globs (asset pools too)"
    )
    v.add_argument("--no-placement", action="store_true", help="skip the placement check")
    v.set_defaults(func=cmd_validate)

    pr = lsub.add_parser("preview", help="top-down PNG of a layout")
    pr.add_argument("layout", type=Path)
    pr.add_argument("--out", type=Path, required=True)
    pr.add_argument("--render", action="store_true", help="add a SAPIEN render beside it")
    pr.add_argument("--size", type=image_side, default=640, help="image side in pixels")
    pr.set_defaults(func=cmd_preview)


MANIFEST = ".embodied_envs_variants"  # in --out (JSON, not *.json): the layout of each stem


def _generate_one(args: tuple[str, int, str]) -> str:
    layout_path, seed, out = args
    layout = load_layout(layout_path, check_files=False)
    placed = place(layout, seed)
    return str(placed.save(Path(out) / f"{Path(layout_path).stem}_{seed:06d}.json"))


def claim_stem(out: Path, layout: Path) -> None:
    """Record that ``out``'s ``<stem>_*.json`` variants come from ``layout``; refuse when they
    come from another layout file of the same stem (its variants would be replaced)."""
    manifest = out / MANIFEST
    try:
        owners = json.loads(manifest.read_text()) if manifest.is_file() else {}
    except (OSError, json.JSONDecodeError):
        owners = {}
    stem, source = layout.stem, str(layout.resolve())
    owner = owners.get(stem)
    if owner is None and any(out.glob(f"{stem}_[0-9]*.json")):
        owner = "a layout this command did not record"
    if owner is not None and owner != source:
        raise SystemExit(
            f"error: --out {out} already holds variants {stem}_*.json of {owner}; this run "
            f"would replace them with variants of {source}. Fix: choose another --out."
        )
    owners[stem] = source
    with atomic_output(manifest) as tmp:
        tmp.write_text(json.dumps(owners, indent=2))


def cmd_generate(args) -> int:
    load_layout(args.layout, check_poses=False)  # validate once, up front (poses re-drawn)
    writable_dir(args.out)
    claim_stem(args.out, args.layout)
    jobs = [(str(args.layout), args.seed + i, str(args.out)) for i in range(args.num)]
    bar = tqdm(total=args.num, desc="placing", unit="layout")
    run(_generate_one, [(job,) for job in jobs], args.workers, on_result=lambda _: bar.update())
    bar.close()
    print(f"wrote {args.num} layouts to {args.out}")
    return 0


def validate_problems(path: Path, check_placement: bool = True) -> list[str]:
    """Every problem of one layout, as user-facing lines (empty when valid)."""
    try:
        layout = load_layout(path)
    except LayoutError as e:
        return e.problems
    except OSError as e:  # unreadable file, permission, a folder given as file, ...
        return [f"{path}: {e.strerror or e} ({e.filename or path}). Fix: check the path."]
    problems, limits = [], PlacementLimits()
    try:  # the robot's reach and movers' clearance, as the env places objects for it
        entry = ROBOTS[resolve_robot(layout.robot, None, str(path))]
        limits = PlacementLimits(**entry.placement)
    except LayoutError as e:
        problems.extend(e.problems)
    problems += annotation_lines(layout)[1]
    splat = layout.gs_model_path()
    if splat.is_file():  # optional: only hybrid rendering needs it, but it must be readable
        try:
            check_ply(splat)
        except (SplatFileError, OSError) as e:
            problems.append(str(e))
    if check_placement:  # with every member of each asset pool in its place
        for member in LayoutSet((layout,), (asset_pools(layout),)).members():
            try:
                place(member, 0, limits)
            except PlacementError as e:
                problems.append(f"placement: {e}")
    return list(dict.fromkeys(problems))


def cmd_validate(args) -> int:
    bad, paths = 0, []
    for spec in args.layouts:
        try:
            paths += layout_files(spec)
        except LayoutError as e:
            bad += 1
            print(f"FAIL {spec}")
            print("\n".join(f"  - {p}" for p in e.problems))
    for path in paths:
        problems = validate_problems(path, not args.no_placement)
        if problems:
            bad += 1
            print(f"FAIL {path}")
            for p in problems:
                print(f"  - {p}")
        else:  # the task as the env grades it (layout/task.py)
            layout = load_layout(path)
            print(f"ok   {path}  task: {layout.task.describe()}")
            for line in decomposed_meshes(layout) + annotation_lines(layout)[0]:
                print(f"     {line}")
    return 1 if bad else 0


def decomposed_meshes(layout: LayoutInfo) -> list[str]:
    """A line per collision mesh of ``layout`` decomposed on load (layout/collision.py)."""
    built = {out: (orig, reason) for orig, (reason, out) in DECOMPOSED.items()}
    lines = []
    for node in layout.assets:
        if node == layout.background:
            continue
        path = layout.asset_spec(node).collision.path
        if path in built:
            orig, reason = built[path]
            parts = len(obj_objects(path))
            lines.append(f"{node}: {orig}: {reason}; decomposed into {parts} convex parts ({path})")
    return lines


def annotation_lines(layout: LayoutInfo) -> tuple[list[str], list[str]]:
    """Per asset with EmbodiedGen's grasp annotations (layout/affordance.py): a line saying how
    many grasps the expert reads, or a problem when the file cannot be read."""
    lines, problems = [], []
    for node in layout.assets:
        if node == layout.background:
            continue
        try:
            path = annotation_path(layout.asset_spec(node).urdf_path)
            if path is not None:
                annot = read_annotation(path)
                parts = len(set(annot.part))
                plural = "s" if parts != 1 else ""
                lines.append(f"{node}: {len(annot)} annotated grasps on {parts} graspable "
                             f"part{plural} ({path})")  # fmt: skip
        except AffordanceError as e:
            problems.append(f"{node}: {e}")
        except LayoutError:
            continue  # the asset's own problem is reported by the layout's checks
    return lines, problems


def draw_top_down(layout: LayoutInfo, size: int = 640, limits: PlacementLimits | None = None):
    """A top-down PIL image: table hull, labelled footprints, robot base, heading, reach band."""
    lim = limits or PlacementLimits()
    ctx = layout.context
    ctx_world = world_vertices(node_geometry(layout, ctx), layout.pose(ctx))
    top = top_surface(ctx_world, lim.top_band)
    robot = layout.pose(layout.robot)
    pts = [top.hull, np.array([robot.p[:2]])]
    lo = np.min(np.concatenate(pts), 0) - 0.25
    hi = np.max(np.concatenate(pts), 0) + 0.25
    scale = (size - 40) / float(max(hi - lo))

    def px(xy):
        xy = np.atleast_2d(xy)
        return [(20 + (x - lo[0]) * scale, size - 20 - (y - lo[1]) * scale) for x, y in xy]

    img = Image.new("RGB", (size, size), (250, 250, 248))
    d = ImageDraw.Draw(img)
    # reach band of manipulated objects
    yaw = robot.yaw
    half = math.radians(lim.max_heading_deg)
    arc = np.linspace(yaw - half, yaw + half, 40)
    centre = lim.reach_centre(np.array(robot.p[:2]), np.float64(yaw))
    outer = np.stack([np.cos(arc), np.sin(arc)], 1) * lim.reach_max + centre
    inner = (np.stack([np.cos(arc), np.sin(arc)], 1) * lim.reach_min + centre)[::-1]
    d.polygon(px(np.concatenate([outer, inner])), fill=(215, 235, 215), outline=(120, 170, 120))
    d.polygon(px(top.hull), outline=(120, 80, 40), width=3)
    colours = {"manipulated_objs": (40, 90, 220), "distractor_objs": (200, 110, 40)}
    for node in layout.object_nodes():
        cat = layout.objs_mapping[node]
        if cat == "context":
            continue
        pose = layout.pose(node)
        foot = rotate(node_footprint(layout, node), np.float64(pose.yaw)) + pose.p[:2]
        d.polygon(px(foot), outline=colours.get(cat, (90, 90, 90)), width=2)
        cx, cy = px(pose.p[:2])[0]
        d.text((cx + 4, cy - 12), node, fill=colours.get(cat, (40, 40, 40)))
    d.polygon(px(square(np.array(robot.p), lim.robot_footprint, robot.yaw)), fill=(60, 60, 60))
    tip = np.array(robot.p[:2]) + 0.2 * np.array([math.cos(yaw), math.sin(yaw)])
    d.line(px(np.array([robot.p[:2], tip])), fill=(220, 30, 30), width=3)
    d.text(px(robot.p[:2])[0], f"  {layout.robot}", fill=(0, 0, 0))
    d.text(
        (8, 4),
        f"{layout.source.name if layout.source else ''}: top-down (x right, y up); "
        f"green band = reach of manipulated objects",
        fill=(0, 0, 0),
    )
    return img


def cmd_preview(args) -> int:
    layout = load_layout(args.layout)
    img = draw_top_down(layout, args.size)
    if args.render:
        env = gym.make(
            "PickEmbodiedGen-v1",
            layout_file=str(args.layout),
            replace_objs=False,
            render_mode="rgb_array",
            camera_cfg=dict(image_hw=[args.size, args.size]),
        )
        env.reset(seed=0)
        frame = env.render()
        env.close()
        frame = np.asarray(frame.cpu().numpy() if hasattr(frame, "cpu") else frame)[0]
        both = Image.new(
            "RGB", (img.width + frame.shape[1], max(img.height, frame.shape[0])), "white"
        )
        both.paste(img, (0, 0))
        both.paste(Image.fromarray(frame), (img.width, 0))
        img = both
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out) as tmp:
        img.save(tmp)
    print(f"wrote {args.out}")
    return 0
