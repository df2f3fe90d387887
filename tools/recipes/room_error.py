"""How well a visual policy's estimator (``perceive.py``) reads the objects' positions in each
room: frames rendered through the dataset's env (placements drawn by seeds from ``ERROR_SEED``,
which no training or evaluation uses; the arm near a demonstrated configuration, as the recipe's
rendered frames), in the layout's own room and in each ``--rooms`` pool, and per room the movers'
xy error (median, 90th percentile, mean) against the env's own state.

    python tools/recipes/room_error.py --policy runs/visual/policy.pt \\
        --demos demos_rgb/default/trajectory.h5 --rooms rooms_held_out/den
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import h5py
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import perceive  # noqa: E402
import perturb  # noqa: E402
import train_policy as tp  # noqa: E402

ERROR_SEED = 1 << 25  # past the recipe's rendered frames (RENDER_SEED up) and any eval seed


def room_errors(policy: Path, demos: Path, rooms: list[str], frames: int, seed: int = 0) -> dict:
    """Per room (``"own"``, then each of ``rooms``), the movers' xy error in metres over
    ``frames`` rendered frames: ``{"median", "p90", "mean", "frames"}``."""
    estimator = torch.jit.load(str(policy)).estimator
    env_info = json.loads(demos.with_suffix(".json").read_text())["env_info"]
    with h5py.File(demos, "r") as f:
        joints = np.concatenate([np.asarray(f[f"{k}/obs/agent/qpos"]) for k in f
                                 if k.startswith("traj_")])  # fmt: skip
    state_env = tp.dataset_env(env_info)
    out = {}
    try:
        slices = perturb.obs_slices(state_env)
        m = perceive.slots(slices)
        for name, pool in [("own", None), *((r, r) for r in rooms)]:
            camera_env = tp.dataset_env(env_info, None, demos, "rgb", rooms=pool)
            try:
                images, _, flats = perceive.rendered_frames(
                    camera_env, state_env, 0.0, joints, perceive.RENDER_SIGMA,
                    np.random.default_rng(seed), least=frames, first=ERROR_SEED,
                )  # fmt: skip
            finally:
                camera_env.close()
            guess = perceive.estimate(estimator, torch.from_numpy(images)).numpy()
            truth = flats[:, perceive.perceived_index(slices)]
            there = flats[:, slices["mover_mask"]] > 0.5  # (N, m)
            miss = (guess - truth)[:, : m * perceive.POS].reshape(len(flats), m, perceive.POS)
            error = np.linalg.norm(miss[..., :2], axis=-1)[there]
            out[name] = {"median": float(np.median(error)), "p90": float(np.percentile(error, 90)),
                         "mean": float(error.mean()), "frames": len(images)}  # fmt: skip
    finally:
        state_env.close()
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--policy", type=Path, required=True, help="a visual policy.pt")
    ap.add_argument("--demos", type=Path, required=True, help="the rgb dataset it was trained on")
    ap.add_argument("--rooms", nargs="*", default=[], help="room pools (FOLDER, GLOB, shipped)")
    ap.add_argument("--frames", type=int, default=200, help="frames per room")
    args = ap.parse_args(argv)
    errors = room_errors(args.policy, args.demos, args.rooms, args.frames)
    for name, e in errors.items():
        print(f"{name}: movers' xy error median {100 * e['median']:.2f} cm, 90th percentile "
              f"{100 * e['p90']:.2f} cm, mean {100 * e['mean']:.2f} cm ({e['frames']} frames)")
    return errors


if __name__ == "__main__":
    main()
