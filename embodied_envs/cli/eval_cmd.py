"""``embodied-envs eval``: a policy on seeded episodes per layout, with a summary."""

from __future__ import annotations

import os
from pathlib import Path

from embodied_envs.cli.args import (
    CAMERA_KEYS,
    DEBUG_ENV,
    LAYOUT_HELP,
    EpisodeBar,
    add_camera_arguments,
    add_config_argument,
    add_ray_argument,
    camera_env_kwargs,
    check_seed_span,
    checked_layouts,
    env_config,
    failure_line,
    layout_value,
    note_workers,
    positive_int,
    ran_on,
    seed_int,
    writable_dir,
)
from embodied_envs.cli.collect import resumed_note
from embodied_envs.cluster import ClusterError
from embodied_envs.pipelines.evaluate import VIDEO_CHOICES, EvalError, EvalPlan, evaluate
from embodied_envs.pipelines.policies import BUILTIN_POLICIES
from embodied_envs.pipelines.resume import ResumeError

# env keywords eval sets itself: a --config file may not set them
OWNED_KEYS = {
    "layout_file": "--layout",
    "obs_mode": "--obs-mode",
    "control_mode": "--control-mode",
    "render_mode": "--video",
    "num_envs": "--workers: one env per process",
    "sim_backend": "one CPU env per process",
    "max_episode_steps": "--max-episode-steps",
    **CAMERA_KEYS,
}
OBS_MODES = (
    "state", "state_dict", "rgb", "depth", "rgbd", "pointcloud", "rgb+depth+segmentation",
    "sensor_data", "none",
)  # fmt: skip


def add_parser(sub) -> None:
    p = sub.add_parser(
        "eval",
        help="evaluate a policy on seeded episodes: success rate with its interval, videos",
        description=(
            "Runs a policy on N seeded episodes per layout (seeds S .. S+N-1) and writes "
            "OUT/episodes.json, OUT/summary.json (success rate and its 95%% Wilson interval, "
            "overall and per layout), OUT/summary.png and, with --video, videos of the first "
            "--video-episodes episodes per layout. POLICY: "
            f"{', '.join(BUILTIN_POLICIES)}, or module:factory / file.py:factory, where "
            "factory(env) returns a callable obs -> action or a torch.nn.Module. An action "
            "that is not a finite array of the action space's shape, or a policy that raises, "
            "stops the run with one line naming the policy, the step and the expected shape."
        ),
    )
    p.add_argument("--policy", required=True, help="expert | random | zero | module:factory")
    p.add_argument("--layout", nargs="+", default=None, help=LAYOUT_HELP)
    p.add_argument("--episodes", type=positive_int, default=10, help="episodes per layout")
    p.add_argument("--seed", type=seed_int, default=0, help="first episode seed")
    p.add_argument("--out", type=Path, default=Path("outputs/eval"))
    p.add_argument("--obs-mode", choices=OBS_MODES, default="state")
    p.add_argument("--control-mode", default=None, help="default: the env's (expert: pd_joint_pos)")
    add_camera_arguments(p)
    p.add_argument(
        "--max-episode-steps",
        type=positive_int,
        default=None,
        help="episode limit (default: the registered 500 control steps)",
    )
    p.add_argument(
        "--video",
        choices=VIDEO_CHOICES,
        default="none",
        help="videos are opt-in: all or fail (unsuccessful ones) films the first "
        "--video-episodes episodes per layout and keeps all or the unsuccessful of them; "
        "none (the default) renders nothing: an episode then costs ~1.1x a bare gym loop",
    )
    p.add_argument(
        "--video-episodes",
        type=positive_int,
        default=2,
        metavar="N",
        help="with --video all|fail: film only the first N episodes of each layout (seeds "
        "S .. S+N-1; default 2). A filmed episode costs ~50x an unfilmed one on the CPU",
    )
    p.add_argument("--workers", type=positive_int, default=None, help="processes (default 1)")
    add_ray_argument(p)
    add_config_argument(p)
    p.set_defaults(func=cmd_eval, builds_env=True)


def cmd_eval(args) -> int:
    # the pipelines import the simulator: only when the command runs, not for --help
    from embodied_envs.pipelines.on_ray import start

    workers = args.workers or (0 if args.ray else 1)  # 0: the Ray cluster's CPUs
    # Ray comes up (its workers importing the episodes' module) while the inputs are checked
    start(args.ray, workers, "embodied_envs.pipelines.evaluate")
    config = env_config(args.config, OWNED_KEYS) | camera_env_kwargs(args)
    layouts = checked_layouts(args.layout)
    if args.policy == "expert" and args.control_mode not in (None, "pd_joint_pos"):
        raise SystemExit(
            f"error: --policy expert drives pd_joint_pos, not --control-mode {args.control_mode}"
        )
    check_seed_span(args.seed, args.episodes, "episodes")
    writable_dir(args.out)
    if not args.ray:
        note_workers(workers)
    plan = EvalPlan(
        policy=args.policy,
        layouts=tuple(layout_value(files) for _, files in layouts),
        episodes=args.episodes,
        seed=args.seed,
        obs_mode=args.obs_mode,
        control_mode=args.control_mode,
        video=args.video,
        video_episodes=args.video_episodes,
        workers=workers,
        env_kwargs=config
        if args.max_episode_steps is None
        else dict(config, max_episode_steps=args.max_episode_steps),
        ray=args.ray,
    )
    with EpisodeBar(len(plan.tasks()), f"eval {args.policy}") as bar:
        try:
            s = evaluate(plan, args.out, progress=bar,
                         on_resume=resumed_note(bar, f"eval {args.policy}"))  # fmt: skip
        except EvalError as e:
            bar.close()
            if e.__cause__ is not None and os.environ.get(DEBUG_ENV):
                raise  # the policy's own traceback
            print(f"error: {e}")
            return 1
        except (ClusterError, ResumeError):
            raise
        except Exception as e:  # an env or a policy failed in a worker: one line
            bar.close()
            print(failure_line("evaluation failed", e))
            return 1
    lo, hi = s["success_ci95"]
    print(
        f"{args.policy}: {s['successes']}/{s['episodes']} successful ({s['success_rate']:.0%}, "
        f"95% interval {lo:.0%}-{hi:.0%}), fail {s['fail_rate']:.0%}, median "
        f"{s['steps_median']:.0f} steps{ran_on(s['workers'], s['nodes']) if args.ray else ''} "
        f"-> {args.out}"
    )
    for layout, b in s["per_layout"].items():
        print(f"  {Path(layout).name}: {b['successes']}/{b['episodes']} ({b['success_rate']:.0%})")
    return 0
