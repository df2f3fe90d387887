"""``embodied-envs collect``: scripted demonstrations in ManiSkill's trajectory format."""

from __future__ import annotations

from pathlib import Path

from embodied_envs.cli.args import (
    CAMERA_KEYS,
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
from embodied_envs.cluster import ClusterError
from embodied_envs.pipelines.resume import ResumeError
from embodied_envs.robots import EXPERT_MODES

# env keywords collect sets itself: a --config file may not set them
OWNED_KEYS = {
    "layout_file": "--layout",
    "obs_mode": "--obs-mode",
    "render_mode": "--video",
    "control_mode": "--control-mode",
    "num_envs": "--workers: one env per process",
    "sim_backend": "one CPU env per process",
    **CAMERA_KEYS,
}


def add_parser(sub) -> None:
    p = sub.add_parser(
        "collect",
        help="scripted demonstrations as a ManiSkill dataset (.h5 + .json)",
        description=(
            "Runs the scripted solver on seeded episodes and writes ManiSkill's trajectory "
            "format per --layout value: OUT/<layout stem>/trajectory.h5, trajectory.json, "
            "summary.json (a folder or glob: one dataset over the layout set, named after the "
            "folder; each episode's seed draws its layout). "
            "Several machines: --ray on a Ray cluster (docs/scaling.md), or disjoint seed ranges "
            "(--seed) joined with python -m mani_skill.trajectory.merge_trajectory."
        ),
    )
    p.add_argument("--layout", nargs="+", default=None, help=LAYOUT_HELP)
    p.add_argument("--num", type=positive_int, default=10, help="demonstrations per layout")
    p.add_argument("--seed", type=seed_int, default=0, help="first episode seed")
    p.add_argument("--out", type=Path, default=Path("outputs/demos"))
    p.add_argument(
        "--obs-mode",
        choices=["none", "state", "rgb", "rgbd"],
        default="none",
        help="recorded observations (none: replay re-renders them, as ManiSkill's demos)",
    )
    add_camera_arguments(p)
    p.add_argument("--only-success", action="store_true", help="keep successful episodes only")
    p.add_argument(
        "--max-attempts",
        type=positive_int,
        default=None,
        help="with --only-success: seeds tried at most (default 2 x --num)",
    )
    p.add_argument("--workers", type=positive_int, default=None, help="processes (default 1)")
    add_ray_argument(p)
    p.add_argument("--video", action="store_true", help="also an MP4 per kept episode")
    p.add_argument(
        "--fixed-hand",
        action="store_true",
        help="grasp top-down at the hand's start orientation and carry without turning it: "
        "demos that convert to pd_ee_delta_pos, which cannot turn the hand",
    )
    p.add_argument(
        "--diverse",
        action="store_true",
        help="the former expert: grasp and arm branch chosen afresh per start, so nearby starts "
        "may give distant paths (default: consistent demos, docs/expert.md)",
    )
    p.add_argument(
        "--control-mode",
        choices=EXPERT_MODES,
        default="pd_joint_pos",
        help="the controller the demos act in, recorded as the expert runs (no conversion "
        "afterwards); default pd_joint_pos. pd_joint_delta_pos is the env's default",
    )
    add_config_argument(p)
    p.set_defaults(func=cmd_collect, builds_env=True)


def cmd_collect(args) -> int:
    # the pipelines import the simulator: only when the command runs, not for --help
    from embodied_envs.pipelines.on_ray import session, start

    workers = args.workers or (0 if args.ray else 1)  # 0: the Ray cluster's CPUs
    # Ray comes up (its workers importing the episodes' module) while the inputs are checked
    start(args.ray, workers, "embodied_envs.pipelines.collect")
    # the pipeline imports the simulator: only when the command runs, not for --help
    from embodied_envs.pipelines.collect import CollectError, CollectPlan, owned_output

    config = env_config(args.config, OWNED_KEYS) | camera_env_kwargs(args)
    layouts = checked_layouts(args.layout)
    # the seeds the run may use (the same for every layout) are valid seeds
    attempts = CollectPlan(layout="", num=args.num, only_success=args.only_success,
                           max_attempts=args.max_attempts).attempts()  # fmt: skip
    check_seed_span(args.seed, attempts, "episode seeds")
    writable_dir(args.out)
    if not args.ray:
        note_workers(workers)
    try:
        with owned_output(args.out), session(args.ray, workers):  # one run per --out
            failed = 0
            for name, files in layouts:
                failed += not _collect_one(name, files, args, workers, config)
    except CollectError as e:
        print(f"error: {e}")
        return 1
    return 1 if failed else 0


def _collect_one(name: str, files, args, workers: int, config: dict) -> bool:
    """One layout's (or layout set's) dataset; False (after one error line) when it could
    not be made."""
    label = files[0].name if len(files) == 1 else f"{name} ({len(files)} layouts)"
    # the pipeline imports the simulator: only when the command runs, not for --help
    from embodied_envs.pipelines.collect import CollectError, CollectPlan, collect

    plan = CollectPlan(
        layout=layout_value(files),
        name=name,
        num=args.num,
        seed=args.seed,
        obs_mode=args.obs_mode,
        hybrid_obs=bool(config.get("hybrid_obs", False)),
        only_success=args.only_success,
        max_attempts=args.max_attempts,
        workers=workers,
        video=args.video,
        fixed_hand=args.fixed_hand,
        diverse=args.diverse,
        control_mode=args.control_mode,
        env_kwargs=config,
        ray=args.ray,
    )
    with EpisodeBar(plan.attempts(), label) as bar:
        try:
            s = collect(plan, args.out, progress=bar, on_resume=resumed_note(bar, label))
        except CollectError as e:
            bar.close()
            print(f"error: {e}")
            return False
        except (ClusterError, ResumeError):
            raise
        except Exception as e:  # a worker's env or solver failed: one line, not a traceback
            bar.close()
            print(failure_line(f"collecting {label} failed", e))
            return False
    print(
        f"{label}: {s.kept} demonstrations ({s.successes}/{s.attempted} successful, "
        f"{s.success_rate:.0%}), mean {s.steps_mean:.0f} steps, {s.wall_time_s:.0f} s"
        f"{ran_on(s.workers, s.nodes) if args.ray else ''} -> {args.out / name}"
    )
    return True


def resumed_note(bar: EpisodeBar, label: str):
    """What a command says, above its bar, when it resumes an interrupted run."""

    def note(kept: int, folder: Path) -> None:
        bar.bar.write(f"{label}: resuming an interrupted run: kept {kept} episode"
                      f"{'s' * (kept != 1)} from {folder}")  # fmt: skip

    return note
