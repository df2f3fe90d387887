"""``embodied-envs demo``: the scripted solver on a layout, written as MP4 videos + summary.

On CPU each env runs in its own process (ManiSkill's CPU simulation holds one env per process).
Env 0 uses the layout file's poses; env k > 0 uses ``place(layout, derive_seed(seed, k))``,
written under ``--out`` (never beside the input), as on the GPU simulation.
"""

from __future__ import annotations

from pathlib import Path

from tqdm import tqdm

from embodied_envs.cli.args import (
    add_config_argument,
    check_seed_span,
    checked_layouts,
    env_config,
    image_side,
    layout_value,
    positive_int,
    seed_int,
)
from embodied_envs.config import CameraSpec, merge_config

# env keywords the demo sets itself: a --config file may not set them
OWNED_KEYS = {
    "layout_file": "--layout",
    "render_mode": "--render-mode",
    "num_envs": "--num-envs: one env per process",
    "replace_objs": "env 0 keeps the file's poses, env k a placed variant",
    "control_mode": "the scripted solver drives pd_joint_pos",
    "sim_backend": "one CPU env per process",
}


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="run the scripted pick-and-place and write videos")
    p.add_argument(
        "--layout",
        default=None,
        help="layout file (default: shipped); a folder or glob is a layout set (env k draws)",
    )
    p.add_argument(
        "--num-envs",
        type=positive_int,
        default=1,
        help="envs tiled side by side in the video, each a process of its own (on CPU, "
        "ManiSkill holds one env per process; see --workers)",
    )
    p.add_argument("--episodes", type=positive_int, default=1)
    p.add_argument("--seed", type=seed_int, default=0)
    p.add_argument(
        "--render-mode",
        choices=["hybrid", "rgb_array"],
        default="hybrid",
        help="hybrid: simulated scene over the layout's splat background",
    )
    cam = CameraSpec()
    p.add_argument("--camera-eye", type=float, nargs=3, help=f"default {list(cam.eye)}")
    p.add_argument("--camera-target", type=float, nargs=3, help=f"default {list(cam.target)}")
    p.add_argument(
        "--image-hw", type=image_side, nargs=2, help=f"default {[cam.height, cam.width]}"
    )
    p.add_argument("--fovy-deg", type=float, help=f"default {cam.fovy_deg}")
    add_config_argument(p)
    p.add_argument(
        "--frame-every", type=positive_int, default=2, help="record every k-th control step"
    )
    p.add_argument("--out", type=Path, default=Path("outputs/demo"))
    p.add_argument(
        "--workers", type=positive_int, default=None, help="processes (default: min(envs, cores))"
    )
    p.set_defaults(func=cmd_demo, builds_env=True)


def cmd_demo(args) -> int:
    # the pipeline imports the simulator: only when the command runs, not for --help
    from embodied_envs.pipelines.demo import DemoPlan, run_demo

    if args.num_envs < 1 or args.episodes < 1:
        raise SystemExit("error: --num-envs and --episodes must be at least 1")
    config = env_config(args.config, OWNED_KEYS)
    camera = dict(
        camera_eye=args.camera_eye,
        camera_target_pt=args.camera_target,
        image_hw=args.image_hw,
        fovy_deg=args.fovy_deg,
    )
    env_kwargs = merge_config(
        config, dict(camera_cfg={k: v for k, v in camera.items() if v is not None})
    )
    CameraSpec.from_cfg(env_kwargs["camera_cfg"])  # a bad camera fails before any output
    # bad input fails here, before any simulation
    ((_, files),) = checked_layouts(None if args.layout is None else [args.layout])
    check_seed_span(args.seed, args.num_envs * args.episodes, "env episodes")
    plan = DemoPlan(
        layout=layout_value(files),
        num_envs=args.num_envs,
        episodes=args.episodes,
        seed=args.seed,
        render_mode=args.render_mode,
        env_kwargs=env_kwargs,
        frame_every=args.frame_every,
        workers=args.workers,
    )
    with tqdm(total=args.num_envs * args.episodes, desc="episodes (env x episode)") as bar:
        summary = run_demo(plan, args.out, progress=bar.update)
    for ep in summary["episodes"]:
        envs = ep["envs"]
        ok = sum(e["success"] for e in envs)
        fails = sum(bool(e["plan_failures"]) for e in envs)
        print(
            f"episode {ep['episode']}: success {ok}/{len(envs)}, plan failures {fails}, "
            f"steps {[e['steps'] for e in envs]}, video {ep['video']}"
        )
    print(f"wrote {args.out / 'summary.json'}")
    return 0
