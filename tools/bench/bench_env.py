#!/usr/bin/env python
"""Benchmark: PickEmbodiedGen-v1 against ManiSkill's PickCube-v1, measured in the same run.

1. Default ``reset()`` time (no reconfiguration: per-episode object placement and goals).
2. Steps/s of 50-step episodes including their resets, state observations.
3. The same with RGB observations: ours composited over the splat (``hybrid_obs=True``),
   PickCube's plain ``rgb``.
4. ``render()`` per frame, ``hybrid`` vs ``rgb_array``, and the one-off background render.
5. Batched compositing time per frame at n = 1, 64 and 1,024 envs (synthetic 128x128 camera
   images and backgrounds on this machine's device: the per-frame work of the GPU path).

Usage: python tools/bench/bench_env.py [--episodes 20] [--resets 200] [--frames 50]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import mani_skill.envs  # noqa: E402,F401
import numpy as np  # noqa: E402
import torch  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.config import SPLAT_Y_UP_TO_Z_UP  # noqa: E402
from embodied_envs.envs.hybrid import CameraBackgrounds, HybridRenderer  # noqa: E402
from embodied_envs.layout.pose import LayoutPose  # noqa: E402
from embodied_envs.paths import default_layout  # noqa: E402


def reset_seconds(env_id: str, resets: int, **kwargs) -> float:
    """Mean seconds per default ``reset()`` (after a seeded first one)."""
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    t = time.perf_counter()
    for _ in range(resets):
        env.reset()
    elapsed = time.perf_counter() - t
    env.close()
    return elapsed / resets


def episode_steps_per_second(env_id: str, episodes: int, length: int = 50, **kwargs) -> float:
    """Steps/s over ``episodes`` episodes of ``length`` random-action steps, resets included."""
    env = gym.make(env_id, **kwargs)
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    for _ in range(10):  # warm-up
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
    actions = rng.uniform(-1, 1, (length, *env.action_space.shape)).astype(np.float32)
    t = time.perf_counter()
    for _ in range(episodes):
        env.reset()
        for a in actions:
            env.step(a)
    elapsed = time.perf_counter() - t
    env.close()
    return episodes * length / elapsed


def render_seconds(render_mode: str, frames: int) -> tuple[float, object]:
    """Median seconds per ``render()`` over random-action steps, and the env's unwrapped."""
    env = gym.make("PickEmbodiedGen-v1", obs_mode="state", render_mode=render_mode)
    env.reset(seed=0)
    env.render()  # warm-up
    rng = np.random.default_rng(0)
    times = []
    for _ in range(frames):
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        t = time.perf_counter()
        env.render()
        times.append(time.perf_counter() - t)
    env.close()
    return statistics.median(times), env.unwrapped


def compositing_seconds(n: int, size: int = 128, repeats: int = 10) -> float:
    """Median seconds of one batched composite of ``n`` envs' camera images."""
    from embodied_envs.layout import load_layout

    device = "cuda" if torch.cuda.is_available() else "cpu"
    splat = load_layout(default_layout()).gs_model_path()
    hybrid = HybridRenderer({splat: default_layout()}, SPLAT_Y_UP_TO_Z_UP, device=device)
    g = torch.Generator().manual_seed(0)
    ids = torch.randint(1, 60, (n, 12), generator=g)
    hybrid.configure(
        ids, ids[:, :1] + 60, [LayoutPose.from_xyz_yaw((0, 0, 0), 0.0)] * n, [splat] * n
    )
    model = torch.eye(4, dtype=torch.float64).expand(n, 4, 4)
    intrinsic = torch.eye(3, dtype=torch.float64).expand(n, 3, 3)
    hybrid.preload(
        "cam",
        CameraBackgrounds(
            model=model.to(device),
            intrinsic=intrinsic.to(device),
            rgb=torch.randint(0, 255, (n, size, size, 3), dtype=torch.uint8).to(device),
            depth=torch.rand((n, size, size), generator=g).to(device) * 3,
            valid=torch.ones(n, dtype=torch.bool, device=device),
        ),
    )
    rgb = torch.randint(0, 255, (n, size, size, 3), dtype=torch.uint8).to(device)
    seg = torch.randint(0, 80, (n, size, size, 1), dtype=torch.int16).to(device)
    depth = torch.randint(0, 3000, (n, size, size, 1), dtype=torch.int16).to(device)
    times = []
    for _ in range(repeats + 1):
        if device == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        images = dict(rgb=rgb, segmentation=seg, depth=depth)
        hybrid.composite("cam", images, model, intrinsic, human=False)
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t)
    assert hybrid.renders == 0, "the synthetic backgrounds were used, none rendered"
    return statistics.median(times[1:])


def background_seconds(n: int, batched: bool, size: int = 128) -> float:
    """Seconds to render ``n`` envs' backgrounds (each its own camera and background yaw):
    one batched call, or one call per env (the previous way)."""
    from embodied_envs.layout import load_layout
    from embodied_envs.splat import PinholeCamera

    device = "cuda" if torch.cuda.is_available() else "cpu"
    splat = load_layout(default_layout()).gs_model_path()
    hybrid = HybridRenderer({splat: default_layout()}, SPLAT_Y_UP_TO_Z_UP, device=device)
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    cams = [
        PinholeCamera.look_at(
            (0.6 * np.cos(a), 0.6 * np.sin(a), 1.1), (0, 0, 0.9), (0, 0, 1), size, size
        )
        for a in angles
    ]
    poses = [LayoutPose.from_xyz_yaw((0, 0, 0), 0.3 * k) for k in range(n)]
    hybrid.render_backgrounds(cams[:1], poses[:1], [splat])  # warm-up
    if device == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    if batched:
        hybrid.render_backgrounds(cams, poses, [splat] * n)
    else:
        for cam, pose in zip(cams, poses, strict=True):
            hybrid.render_backgrounds([cam], [pose], [splat])
    if device == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--episodes", type=int, default=20, help="50-step episodes per env")
    ap.add_argument("--resets", type=int, default=200)
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument(
        "--background-envs", type=int, nargs="+", default=[8], help="envs per background batch"
    )
    args = ap.parse_args()
    ours = reset_seconds("PickEmbodiedGen-v1", args.resets, obs_mode="state")
    base = reset_seconds("PickCube-v1", args.resets, obs_mode="state")
    print(
        f"default reset:                     PickEmbodiedGen-v1 {ours * 1e3:6.1f} ms, "
        f"PickCube-v1 {base * 1e3:6.1f} ms, ratio {ours / base:.2f} (target <= 2)"
    )
    for label, ours_kw, base_kw in (
        ("state obs", dict(obs_mode="state"), dict(obs_mode="state")),
        ("rgb obs (ours hybrid)", dict(obs_mode="rgb", hybrid_obs=True), dict(obs_mode="rgb")),
    ):
        ours = episode_steps_per_second("PickEmbodiedGen-v1", args.episodes, **ours_kw)
        base = episode_steps_per_second("PickCube-v1", args.episodes, **base_kw)
        print(
            f"50-step episodes, {label + ':':23s} PickEmbodiedGen-v1 {ours:6.1f} steps/s, "
            f"PickCube-v1 {base:6.1f} steps/s, ratio {ours / base:.2f} (target >= 0.9)"
        )
    rgb, _ = render_seconds("rgb_array", args.frames)
    hyb, u = render_seconds("hybrid", args.frames)
    print(
        f"render() per frame (256x256):      hybrid {hyb * 1e3:6.1f} ms, "
        f"rgb_array {rgb * 1e3:6.1f} ms, ratio {hyb / rgb:.2f}"
    )
    gaussians = sum(len(s) for s in u.hybrid.splats.values())
    print(
        f"background render:                 {u.hybrid.render_seconds / u.hybrid.renders:.2f} s "
        f"per (camera, env), once per configuration ({gaussians:,} Gaussians)"
    )
    for n in args.background_envs:
        one_call = background_seconds(n, batched=True)
        per_env = background_seconds(n, batched=False)
        print(
            f"backgrounds of {n:4d} envs (128x128): one batched call {one_call:7.2f} s, one call "
            f"per env {per_env:7.2f} s, ratio {one_call / per_env:.2f}"
        )
    device = "cuda" if torch.cuda.is_available() else "cpu"
    for n in (1, 64, 1024):
        s = compositing_seconds(n)
        print(
            f"batched compositing, {n:5d} envs:   {s * 1e3:8.2f} ms per frame "
            f"({s / n * 1e6:7.1f} us per env, 128x128, {device})"
        )


if __name__ == "__main__":
    main()
