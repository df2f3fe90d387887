"""``embodied-envs demo``: the scripted solver on a layout, written as MP4 videos + summary.

On CPU each env runs in its own process (ManiSkill's CPU simulation holds one env per process).
Env 0 uses the layout file's poses; env k > 0 uses ``place(layout, derive_seed(seed, k))``,
written under ``--out`` (never beside the input), as on the GPU simulation.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from embodied_envs.cli.args import (
    add_config_argument,
    env_config,
    image_side,
    positive_int,
    seed_int,
)
from embodied_envs.config import CameraSpec, merge_config
from embodied_envs.layout import load_layout
from embodied_envs.layout.placement import derive_seed, place
from embodied_envs.paths import atomic_output, default_layout
from embodied_envs.registration import CONTROL_FREQ, ENV_ID
from embodied_envs.workers import run

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
    p.add_argument("--layout", type=Path, default=None, help="layout file (default: shipped)")
    p.add_argument("--num-envs", type=positive_int, default=1)
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
    p.set_defaults(func=cmd_demo)


@dataclass
class EnvEpisode:
    episode: int
    env: int
    seed: int
    layout: str
    success: bool
    steps: int
    plan_failures: list[str]
    wall_time_s: float
    frames: list = field(default_factory=list, repr=False)


def _run_env(job: dict) -> list[EnvEpisode]:
    """All episodes of one env, in its own process."""
    import gymnasium as gym

    import embodied_envs  # noqa: F401
    from embodied_envs.solvers import PickPlaceSolver

    env = gym.make(
        ENV_ID,
        **job["env_kwargs"],
        layout_file=job["layout"],
        replace_objs=False,
        render_mode=job["render_mode"],
        control_mode="pd_joint_pos",
    )
    out = []
    every = job["frame_every"]
    try:
        for e, seed in enumerate(job["seeds"]):
            t0 = time.perf_counter()
            env.reset(seed=seed)
            frames = [_frame(env)]
            recorder = _Recorder(env, frames, every)
            result = PickPlaceSolver(recorder, seed=seed).solve()
            frames.append(_frame(env))
            out.append(
                EnvEpisode(
                    episode=e,
                    env=job["env"],
                    seed=seed,
                    layout=job["layout"],
                    success=bool(result.success[0]),
                    steps=result.steps,
                    plan_failures=result.reports[0].plan_failures,
                    wall_time_s=round(time.perf_counter() - t0, 3),
                    frames=frames,
                )
            )
    finally:
        env.close()
    return out


def _frame(env) -> np.ndarray:
    img = env.render()
    img = img.cpu().numpy() if hasattr(img, "cpu") else np.asarray(img)
    return img[0] if img.ndim == 4 else img


class _Recorder:
    """Passes steps through to the env and keeps every k-th rendered frame."""

    def __init__(self, env, frames: list, every: int):
        self.env, self.frames, self.every, self.t = env, frames, every, 0
        self.unwrapped = env.unwrapped
        self.action_space = env.action_space

    def step(self, action):
        res = self.env.step(action)
        self.t += 1
        if self.t % self.every == 0:
            self.frames.append(_frame(self.env))
        return res


def tile(frames: list[np.ndarray]) -> np.ndarray:
    """Tile equally sized frames into a near-square grid."""
    n = len(frames)
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    h, w, c = frames[0].shape
    grid = np.zeros((rows * h, cols * w, c), np.uint8)
    for i, f in enumerate(frames):
        r, col = divmod(i, cols)
        grid[r * h : (r + 1) * h, col * w : (col + 1) * w] = f
    return grid


def write_video(path: Path, per_env_frames: list[list[np.ndarray]], fps: int) -> int:
    """Tile the envs' frames over time (shorter episodes hold their last frame); returns #frames."""
    import imageio.v2 as imageio

    n = max(len(f) for f in per_env_frames)
    with (
        atomic_output(path) as tmp,
        imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=1) as w,
    ):
        for t in range(n):
            w.append_data(tile([f[min(t, len(f) - 1)] for f in per_env_frames]))
    return n


def env_layouts(layout_path: Path, num_envs: int, seed: int, out: Path) -> list[str]:
    """Env 0: the file itself; env k > 0: a placed variant written under ``out``."""
    base = load_layout(layout_path)
    paths = [str(layout_path.resolve())]
    for k in range(1, num_envs):
        placed = place(base, derive_seed(seed, k))
        paths.append(str(placed.save(out / "layouts" / f"env{k}.json")))
    return paths


def cmd_demo(args) -> int:
    layout_path = (args.layout or default_layout()).resolve()
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
    args.out.mkdir(parents=True, exist_ok=True)
    layouts = env_layouts(layout_path, args.num_envs, args.seed, args.out)
    jobs = [
        dict(
            env=k,
            layout=layouts[k],
            render_mode=args.render_mode,
            env_kwargs=env_kwargs,
            frame_every=args.frame_every,
            seeds=[args.seed + e * args.num_envs + k for e in range(args.episodes)],
        )
        for k in range(args.num_envs)
    ]
    t0 = time.perf_counter()
    bar = tqdm(total=args.num_envs * args.episodes, desc="episodes (env x episode)")
    workers = 1 if args.num_envs == 1 else args.workers or min(args.num_envs, os.cpu_count() or 1)
    results = run(
        _run_env, [(job,) for job in jobs], workers, on_result=lambda r: bar.update(len(r))
    )
    bar.close()
    fps = max(1, int(round(CONTROL_FREQ / args.frame_every)))
    summary = dict(
        layout=str(layout_path),
        num_envs=args.num_envs,
        seed=args.seed,
        render_mode=args.render_mode,
        fps=fps,
        episodes=[],
    )
    for e in range(args.episodes):
        eps = [results[k][e] for k in range(args.num_envs)]
        video = args.out / f"episode_{e:03d}.mp4"
        n_frames = write_video(video, [ep.frames for ep in eps], fps)
        envs = [{k: v for k, v in asdict(ep).items() if k != "frames"} for ep in eps]
        summary["episodes"].append(
            dict(
                episode=e,
                video=str(video),
                frames=n_frames,
                success_rate=float(np.mean([ep.success for ep in eps])),
                envs=envs,
            )
        )
        ok = sum(ep.success for ep in eps)
        fails = sum(bool(ep.plan_failures) for ep in eps)
        print(
            f"episode {e}: success {ok}/{len(eps)}, plan failures {fails}, "
            f"steps {[ep.steps for ep in eps]}, video {video}"
        )
    summary["wall_time_s"] = round(time.perf_counter() - t0, 2)
    with atomic_output(args.out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.out / 'summary.json'}")
    return 0
