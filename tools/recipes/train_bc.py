#!/usr/bin/env python
"""Train a state-based behaviour-cloning policy on a dataset of this env, on the CPU, in minutes.

The policy is an MLP (two hidden layers of 256, ReLU), as ManiSkill's state BC baseline uses,
trained by mean squared error on (observation, action) pairs read with ManiSkill's own
``ManiSkillTrajectoryDataset``; observations are normalised per dimension with the dataset's
mean and standard deviation, and actions clamped to the range the dataset's actions span. It is
saved as a TorchScript file that ``embodied-envs eval --policy OUT/policy.pt`` runs, with
``OUT/train.json`` (the dataset, control mode, sizes, final loss, seconds).

The recipe (docs/evaluation.md), on the default layout:

    embodied-envs collect --layout layouts/default.json --num 100 --seed 0 --only-success \\
        --out demos
    embodied-envs replay --traj-path demos/default/trajectory.h5 -o state \\
        -c pd_joint_delta_pos --save-traj
    python tools/recipes/train_bc.py \\
        --demos demos/default/trajectory.state.pd_joint_delta_pos.physx_cpu.h5 --out runs/bc
    embodied-envs eval --policy runs/bc/policy.pt --control-mode pd_joint_delta_pos \\
        --layout layouts/default.json --episodes 50 --seed 10000 --out outputs/eval_bc

Usage: python tools/recipes/train_bc.py --demos FILE.h5 --out DIR [--iters 20000] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset
from torch import nn

from embodied_envs.paths import atomic_output


class BCPolicy(nn.Module):
    """Observation -> action: normalise, MLP, clamp to the demonstrated range."""

    def __init__(self, obs_mean, obs_std, act_low, act_high, hidden: int = 256):
        super().__init__()
        obs_dim, act_dim = len(obs_mean), len(act_low)
        self.register_buffer("obs_mean", torch.as_tensor(obs_mean, dtype=torch.float32))
        self.register_buffer("obs_std", torch.as_tensor(obs_std, dtype=torch.float32))
        self.register_buffer("act_low", torch.as_tensor(act_low, dtype=torch.float32))
        self.register_buffer("act_high", torch.as_tensor(act_high, dtype=torch.float32))
        self.net = nn.Sequential(
            nn.Linear(obs_dim, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, act_dim),
        )

    def raw(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net((obs - self.obs_mean) / self.obs_std)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.clamp(self.raw(obs), self.act_low, self.act_high)


def load_pairs(path: Path, num_demos: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """The dataset's state observations and actions, and its ``env_info``."""
    data = ManiSkillTrajectoryDataset(str(path), load_count=num_demos)
    obs = data.obs
    if not isinstance(obs, np.ndarray) or obs.ndim != 2:
        sys.exit(
            f"{path}: the observations are not a state vector (obs_mode 'state'). Fix: "
            "replay it with `embodied-envs replay --traj-path ... -o state --save-traj`"
        )
    if len(data.actions) != len(obs):
        sys.exit(f"{path}: {len(obs)} observations for {len(data.actions)} actions")
    return obs.astype(np.float32), data.actions.astype(np.float32), data.env_info


def train(args: argparse.Namespace) -> dict:
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    obs, actions, env_info = load_pairs(args.demos, args.num_demos)
    mean, std = obs.mean(0), obs.std(0) + 1e-6
    policy = BCPolicy(mean, std, actions.min(0), actions.max(0))
    optim = torch.optim.Adam(policy.parameters(), lr=args.lr)
    x, y = torch.from_numpy(obs), torch.from_numpy(actions)
    start, loss = time.perf_counter(), torch.tensor(float("nan"))
    for it in range(args.iters):
        batch = torch.from_numpy(rng.integers(0, len(x), args.batch_size))
        loss = nn.functional.mse_loss(policy.raw(x[batch]), y[batch])
        optim.zero_grad()
        loss.backward()
        optim.step()
        if it % 5000 == 0:
            print(f"iteration {it}: loss {loss.item():.5f}", flush=True)
    seconds = time.perf_counter() - start
    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out / "policy.pt") as tmp:
        torch.jit.save(torch.jit.script(policy.eval()), str(tmp))
    kwargs = env_info.get("env_kwargs", {})
    info = {
        "demos": str(args.demos),
        "env_id": env_info.get("env_id"),
        "control_mode": kwargs.get("control_mode"),
        "layout_file": kwargs.get("layout_file"),
        "pairs": len(x),
        "obs_dim": int(x.shape[1]),
        "act_dim": int(y.shape[1]),
        "iters": args.iters,
        "batch_size": args.batch_size,
        "lr": args.lr,
        "seed": args.seed,
        "final_loss": float(loss.item()),
        "train_seconds": round(seconds, 1),
    }
    with atomic_output(args.out / "train.json") as tmp:
        tmp.write_text(json.dumps(info, indent=2) + "\n")
    return info


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--demos", type=Path, required=True, help="a state dataset (.h5)")
    ap.add_argument("--out", type=Path, required=True, help="folder for policy.pt, train.json")
    ap.add_argument("--num-demos", type=int, default=-1, help="episodes to load (-1: all)")
    ap.add_argument("--iters", type=int, default=20_000)
    ap.add_argument("--batch-size", type=int, default=1024)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if not args.demos.is_file() or not args.demos.with_suffix(".json").is_file():
        sys.exit(f"{args.demos}: no such dataset (an .h5 with its .json beside it)")
    info = train(args)
    print(json.dumps(info, indent=2))
    mode = info["control_mode"]
    print(
        f"evaluate: embodied-envs eval --policy {args.out / 'policy.pt'} --control-mode {mode}"
        " --layout LAYOUT --episodes 50 --seed 10000 --out OUT"
    )


if __name__ == "__main__":
    main()
