"""GPU-machine probe (tools/gpu/env.sh first): the CPU simulation rendering on the GPU, and the
PyTorch splat rasterizer on CUDA against the CPU, per views-per-call and per pairs-per-chunk.

Usage: python3 tools/gpu/probe.py [--chunks 19 21 23]
"""

import argparse
import time

import gymnasium as gym
import torch

import embodied_envs  # noqa: F401
from embodied_envs.paths import data_root
from embodied_envs.splat import PinholeCamera, rasterizer, read_ply, render


def timed(splat, cams, repeats=3):
    render(splat, cams, backend="torch")  # warm-up
    if splat.device.type == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(repeats):
        out = render(splat, cams, backend="torch")
    if splat.device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - start) / repeats / len(cams) * 1000, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--chunks", type=int, nargs="+", default=[24], help="log2 pairs per chunk")
    args = ap.parse_args()
    e = gym.make("PickEmbodiedGen-v1", obs_mode="rgbd", render_mode="hybrid", hybrid_obs=True)
    e.reset(seed=0)
    frame = e.render()
    print("cpu-sim hybrid frame", tuple(frame.shape), "mean", round(frame.float().mean().item(), 2))
    start = time.perf_counter()
    for _ in range(20):
        e.step(e.action_space.sample())
    print(f"20 rgbd hybrid steps {time.perf_counter() - start:.3f} s")
    e.close()

    splat = read_ply(data_root() / "assets" / "background" / "gs_model.ply")
    cams = [
        PinholeCamera.look_at((0.02 * k, 1.3, 0.01 * k), (2.0, 1.0, -1.0), up=(0, 1, 0))
        for k in range(64)
    ]
    cpu_ms, ref = timed(splat, cams[:16], repeats=1)
    print(f"cpu 16 views: {cpu_ms:.1f} ms/view")
    gpu = splat.to("cuda")
    for log2 in args.chunks:
        rasterizer.MAX_PAIRS_PER_CHUNK_CUDA = 1 << log2
        for n in (1, 16, 64):
            ms, out = timed(gpu, cams[:n])
            line = f"cuda chunk 2^{log2} {n:>2} views: {ms:6.2f} ms/view ({cpu_ms / ms:.1f}x cpu)"
            if n == 16:
                off = ((out.rgb.cpu() - ref.rgb).abs() > 2 / 255).float().mean().item()
                line += f", pixels off the cpu image by > 2/255: {off:.4%}"
            print(line)


if __name__ == "__main__":
    main()
