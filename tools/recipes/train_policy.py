#!/usr/bin/env python
"""Train a state policy on a dataset of this env, on the CPU, in minutes: behaviour cloning with
action chunking, executed with temporal ensembling (ACT's scheme, with an MLP in place of its
transformer).

The policy maps a state observation to the next ``--chunk`` actions. Observations are normalised
per dimension with the dataset's mean and standard deviation (dimensions that never vary keep
scale 1), and the observation groups named by ``--drop`` (e.g. ``qvel``) are zeroed; training
adds Gaussian noise of ``--obs-noise`` standard deviations to the normalised observation. The loss
is L1 on the normalised actions (per step of the chunk), with the steps of a chunk past its
episode's end left out. At run time each step's chunk is added to a running weighted sum of the
predictions for the coming steps (the prediction made ``j`` steps ahead of the step it is for
weighs ``exp(-decay * j)``; ``--decay -0.1``, the default: the older weigh more, as in ACT, so
that an action predicted for a step is taken there, not postponed by each newer prediction),
and the step's action is that weighted mean, clamped to the
demonstrated range. The module keeps that sum per env; its ``reset()`` (TorchScript-exported,
called by ``embodied-envs eval`` at each episode start) clears it.

``--frame target`` (the default): an arm controller that adds its action to the joints' positions
(``pd_joint_delta_pos``: target = joints now + action) is learned and ensembled in the joint
targets its actions set, as ACT and diffusion policy predict absolute joint targets: the chunk
predicted at step ``t`` is the targets of steps ``t..t+chunk-1`` less the joints at ``t``, the
ensemble sums targets, and the action run at a step is the ensembled target less the joints
then. Learned as deltas (``--frame action``), a prediction's error is a joint velocity that the
controller integrates (the arm drifts away and never holds still); as targets it is an offset.

Training runs for ``--minutes`` of wall-clock time (cosine learning-rate decay over that time),
then writes ``OUT/policy.pt`` (TorchScript, run by ``embodied-envs eval --policy OUT/policy.pt``)
and ``OUT/train.json`` (the dataset, control mode, sizes, settings, iterations, final loss).

    embodied-envs collect --layout layouts/default.json --num 200 --seed 0 --only-success \\
        --obs-mode state --control-mode pd_joint_delta_pos --out demos
    python tools/recipes/train_policy.py --demos demos/default/trajectory.h5 --out runs/act \\
        --minutes 20
    embodied-envs eval --policy runs/act/policy.pt --control-mode pd_joint_delta_pos \\
        --layout layouts/default.json --episodes 30 --seed 10000 --out outputs/eval_act
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import torch
from torch import nn

from embodied_envs.paths import atomic_output

sys.path.insert(0, str(Path(__file__).resolve().parent))
import perturb  # noqa: E402
import visual  # noqa: E402
from ensemble import TemporalEnsemble  # noqa: E402

# one thread: on the shared 2-core machine (load 20) a training step took 3x longer with two
# (7.8 against 2.5 steps/s, a 256x256 MLP), whose threads wait for each other
TORCH_THREADS = 1
VISUAL_THREADS = os.cpu_count() or 1  # a visual policy's convolutions use every core
MIN_STD = 1e-3  # a dimension varying less than this over the dataset is not rescaled
LOG_EVERY_S = 30.0  # seconds between progress lines
ARTICULATION_POSE_VEL = 13  # an articulation's recorded state: root pose (7), velocities (6), ...


class ChunkPolicy(nn.Module):
    """Observation -> the next ``chunk`` actions (``raw``), and the temporally ensembled action
    of this step (``forward``), per env of the batch."""

    def __init__(
        self, obs_mean, obs_std, obs_keep, act_mean, act_std, act_low, act_high,
        chunk: int, hidden: list[int], decay: float, frame: tuple[np.ndarray, np.ndarray],
    ):  # fmt: skip
        super().__init__()
        obs_dim, act_dim = len(obs_mean), len(act_low)
        self.chunk, self.act_dim = chunk, act_dim
        coef, joint = frame  # target_frame: per action, its joint's observed position's weight
        for name, value in dict(
            obs_mean=obs_mean, obs_std=obs_std, obs_keep=obs_keep, act_mean=act_mean,
            act_std=act_std, act_low=act_low, act_high=act_high, coef=coef,
        ).items():  # fmt: skip
            self.register_buffer(name, torch.as_tensor(np.asarray(value), dtype=torch.float32))
        self.register_buffer("joint", torch.as_tensor(np.asarray(joint), dtype=torch.long))
        layers: list[nn.Module] = []
        size = obs_dim
        for width in hidden:
            layers += [nn.Linear(size, width), nn.ReLU()]
            size = width
        layers.append(nn.Linear(size, chunk * act_dim))
        self.net = nn.Sequential(*layers)
        self.ensemble = TemporalEnsemble(chunk, act_dim, decay)

    def normalise(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs - self.obs_mean) / self.obs_std * self.obs_keep

    def raw_normalised(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised observations -> normalised action chunks ``(B, chunk, A)``."""
        return self.net(x).view(-1, self.chunk, self.act_dim)

    def raw(self, obs: torch.Tensor) -> torch.Tensor:
        """Observations -> action chunks ``(B, chunk, A)`` in the env's action units, each step's
        relative to the joints of ``obs`` (the actions were the joints to stay there)."""
        return self.raw_normalised(self.normalise(obs)) * self.act_std + self.act_mean

    def anchor(self, obs: torch.Tensor) -> torch.Tensor:
        """``(B, A)``: what the actions of a delta-joint controller are relative to in
        ``obs`` (its joints' positions over the action's scale; 0 for the other actions)."""
        return obs[:, self.joint] * self.coef

    def targets(self, obs: torch.Tensor) -> torch.Tensor:
        """Observations -> the chunks as targets ``(B, chunk, A)``: :meth:`raw` plus the
        anchor (a delta-joint controller's joint targets, in action units)."""
        return self.raw(obs) + self.anchor(obs)[:, None]

    @torch.jit.export
    def reset(self) -> None:
        """Forget every env's pending predictions (an episode starts)."""
        self.ensemble.reset()

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        action = self.ensemble(self.targets(obs), self.anchor(obs))
        return torch.clamp(action, self.act_low, self.act_high)


def load_episodes(path: Path, num_demos: int) -> tuple[list, list, list, dict]:
    """Each episode's state observations ``(T+1, D)``, actions ``(T, A)`` and the robot's
    recorded base poses ``(T+1, 7)``, and the dataset's ``env_info``."""
    meta = json.loads(path.with_suffix(".json").read_text())
    episodes = meta["episodes"][: num_demos if num_demos > 0 else None]
    observations, actions, bases = [], [], []
    robot = agent_groups(path)[1] if episodes else ""
    with h5py.File(path, "r") as f:
        for ep in episodes:
            traj = f[f"traj_{ep['episode_id']}"]
            if not isinstance(traj["obs"], h5py.Dataset) or traj["obs"].ndim != 2:
                sys.exit(
                    f"{path}: the observations are not a state vector. Fix: collect with "
                    "--obs-mode state, or replay it with `embodied-envs replay --traj-path ... "
                    "-o state --save-traj`"
                )
            observations.append(np.asarray(traj["obs"], np.float32))
            actions.append(np.asarray(traj["actions"], np.float32))
            bases.append(np.asarray(traj["env_states"]["articulations"][robot][:, : perturb.POSE]))
    if not episodes:
        sys.exit(f"{path}: no episodes")
    return observations, actions, bases, meta["env_info"]


def chunk_targets(
    actions: list[np.ndarray], chunk: int, hold: bool, anchors: list[np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per step of every episode, its next ``chunk`` actions ``(N, chunk, A)`` and which of them
    count in the loss ``(N, chunk)``. Past the episode's end: the last action repeated, counted
    with ``hold`` (the arm is still at a success: the policy learns to stay), else left out.

    ``anchors`` (per episode ``(T, A)``, :meth:`ChunkPolicy.anchor` of its observations): each
    action ``j`` steps ahead is taken relative to the step's own anchor, not its own step's (a
    delta-joint controller's target ``a[t+j] + anchor[t+j]``, less ``anchor[t]``)."""
    targets, valid = [], []
    for e, acts in enumerate(actions):
        steps = len(acts)
        index = np.minimum(np.arange(steps)[:, None] + np.arange(chunk)[None, :], steps - 1)
        target = acts[index]
        if anchors is not None:
            anchor = anchors[e][:steps]
            target = target + anchor[index] - anchor[:, None]
        targets.append(target)
        valid.append(np.ones_like(index, bool) if hold else
                     np.arange(steps)[:, None] + np.arange(chunk)[None, :] < steps)  # fmt: skip
    return np.concatenate(targets), np.concatenate(valid)


def dataset_env(
    env_info: dict, layout: Path | None = None, demos: Path | None = None,
    obs_mode: str = "state_dict", **overrides,
):  # fmt: skip
    """The dataset's env, made once, with the state observation as a dict (its groups' slices)
    or ``obs_mode``; ``layout`` in place of the layout file the dataset names (a dataset moved
    between machines); ``overrides`` other env keywords (another room pool)."""
    import gymnasium as gym

    kwargs = dict(env_info.get("env_kwargs", {}), obs_mode=obs_mode, render_mode=None)
    kwargs |= overrides
    if layout is not None:
        kwargs["layout_file"] = str(layout)
    named = kwargs.get("layout_file")
    if named is not None and not Path(named).exists():
        sys.exit(f"{demos}: env_info.env_kwargs.layout_file {named} does not exist here. Fix: "
                 "--layout FILE, the layout the demonstrations were collected on")  # fmt: skip
    return gym.make(env_info["env_id"], **kwargs)


def target_frame(env, obs_dim: int, act_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Per action value, ``(coef, joint)``: for an arm controller that adds its action to the
    joints' positions (ManiSkill's ``use_delta`` without ``use_target``: ``pd_joint_delta_pos``),
    the observed joint it moves (``qpos`` leads the state observation) and one over the action's
    scale, so that ``action + coef * obs[joint]`` is the joint target it sets (in action units,
    less a constant); 0 for every other action. Read from the dataset's env's controller."""
    controller = env.unwrapped.agent.controller
    parts = getattr(controller, "controllers", {"all": controller})
    mapping = getattr(controller, "action_mapping", {"all": (0, act_dim)})
    coef, joint = np.zeros(act_dim, np.float32), np.zeros(act_dim, np.int64)
    for uid, part in parts.items():
        cfg, (start, end) = part.config, mapping[uid]
        joints = np.asarray(part.active_joint_indices.cpu()).reshape(-1)
        relative = getattr(cfg, "use_delta", False) and not getattr(cfg, "use_target", True)
        if not relative or len(joints) != end - start or joints.max() >= obs_dim:
            continue
        half = np.ones(len(joints))
        if getattr(part, "_normalize_action", False):  # actions in [-1, 1]: lower..upper
            low, high = (np.broadcast_to(np.asarray(v, np.float64), half.shape)
                         for v in (cfg.lower, cfg.upper))  # fmt: skip
            half = (high - low) / 2
        coef[start:end], joint[start:end] = 1.0 / half, joints
    return coef, joint


def with_corrective_copies(
    args, env, episodes: tuple[list, list, list], obs, targets, valid, frame,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The training pairs with ``--perturb-copies`` corrective copies of every step added
    (``perturb.py``): the arm's observed joints moved by ``--perturb`` radians, the observation
    recomputed, the chunk the same joint targets less the moved joints. ``episodes``: the
    observations, actions and base poses :func:`load_episodes` read."""
    observations, actions, bases = episodes
    coef, joint = frame
    arm, hand = np.flatnonzero(coef), np.flatnonzero(coef == 0)
    if args.perturb <= 0 or args.perturb_copies < 1:
        return obs, targets, valid
    if not len(arm):
        sys.exit(
            f"{args.demos}: --perturb needs a controller whose actions are joint deltas "
            "(pd_joint_delta_pos). Fix: --perturb 0, or collect with that controller"
        )
    slices = perturb.obs_slices(env)
    base = np.concatenate([b[: len(a)] for b, a in zip(bases, actions, strict=True)])
    copies, index, offset = perturb.corrective_copies(
        obs, base, joint[arm], perturb.Kinematics(env), slices, args.perturb,
        args.perturb_copies, np.random.default_rng(args.seed + 1),
    )  # fmt: skip
    moved = targets[index].copy()
    moved[:, :, arm] -= (offset * coef[arm])[:, None, :]  # the same targets from moved joints
    # the hand's other actions (its gripper) as at the episode's start (open) where the copy's
    # TCP is off the demonstrated one and nothing is held: the expert closes at its grasp only
    # (a held copy keeps the demonstrated ones: the release ahead, learned from them)
    tcp = slices["tcp_pose"].start
    off = np.linalg.norm(copies[:, tcp : tcp + 3] - obs[index, tcp : tcp + 3], axis=1)
    held = obs[index, slices["is_grasped"].start] > 0.5
    first = np.concatenate([np.repeat(a[:1], len(a), 0) for a in actions])[index]
    reopen = np.flatnonzero((off > perturb.GRASP_TOL) & ~held)
    moved[reopen[:, None], :, hand[None, :]] = first[reopen[:, None], hand[None, :]][:, :, None]
    return (np.concatenate([obs, copies]), np.concatenate([targets, moved]),
            np.concatenate([valid, valid[index]]))  # fmt: skip


def agent_groups(path: Path) -> tuple[dict[str, slice], str]:
    """The slices of the flat state observation that hold the robot's ``qpos`` and ``qvel``
    (ManiSkill's agent state leads it), and the robot's name among the recorded articulations,
    found by matching the recorded observation of the first episode against a recorded
    articulation's joint state (ManiSkill's articulation state: pose 7, velocities 6, then
    ``qpos`` and ``qvel``)."""
    with h5py.File(path, "r") as f:
        traj = f[next(iter(f.keys()))]
        obs = np.asarray(traj["obs"])
        for name, node in traj["env_states"]["articulations"].items():
            state = np.asarray(node)
            dof = (state.shape[1] - ARTICULATION_POSE_VEL) // 2
            joints = state[:, ARTICULATION_POSE_VEL:]
            if 2 * dof <= obs.shape[1] and np.array_equal(obs[:, : 2 * dof], joints):
                return {"qpos": slice(0, dof), "qvel": slice(dof, 2 * dof)}, name
    sys.exit(f"{path}: no recorded articulation's qpos and qvel lead the observation")


def keep_mask(
    drop: list[str], path: Path, obs_dim: int, slices: dict[str, slice] | None = None
) -> np.ndarray:
    """1 per observation value the policy sees, 0 for those of the groups in ``drop`` (found in
    ``slices``, else in the dataset's recorded state observation)."""
    keep = np.ones(obs_dim, np.float32)
    if drop:
        groups = slices if slices is not None else agent_groups(path)[0]
        for name in drop:
            keep[groups[name]] = 0.0
    return keep


def fit(
    policy: nn.Module, args, batch_loss, pairs: int, rng, minutes: float | None = None,
    export: nn.Module | None = None, save: bool = True, name: str = "",
) -> tuple[int, float, float]:  # fmt: skip
    """Train ``policy`` for ``minutes`` (default ``args.minutes``) of wall clock: AdamW
    (``args.lr``, cosine decay over the time budget, ``args.weight_decay``), each iteration
    minimising ``batch_loss`` of ``args.batch_size`` pairs drawn from ``pairs``; a progress line
    every ``LOG_EVERY_S``; then, with ``save``, ``OUT/policy.pt``: ``export`` (default
    ``policy``) as TorchScript. Returns the iterations, the last loss and the
    seconds."""
    optim = torch.optim.AdamW(policy.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    budget = (args.minutes if minutes is None else minutes) * 60.0
    start = last_log = time.perf_counter()
    iters, loss = 0, torch.tensor(float("nan"))
    while (elapsed := time.perf_counter() - start) < budget:
        for group in optim.param_groups:  # cosine decay over the time budget
            group["lr"] = args.lr * 0.5 * (1.0 + math.cos(math.pi * elapsed / budget))
        loss = batch_loss(torch.from_numpy(rng.integers(0, pairs, args.batch_size)))
        optim.zero_grad()
        loss.backward()
        optim.step()
        iters += 1
        if time.perf_counter() - last_log > LOG_EVERY_S:
            last_log = time.perf_counter()
            print(f"{name}{elapsed / 60:5.1f} min, iteration {iters}: loss {loss.item():.4f}",
                  flush=True)  # fmt: skip
    seconds = time.perf_counter() - start
    if save:
        args.out.mkdir(parents=True, exist_ok=True)
        with atomic_output(args.out / "policy.pt") as tmp:
            module = policy if export is None else export
            torch.jit.save(torch.jit.script(module.eval()), str(tmp))
    return iters, float(loss.item()), seconds


def train(args: argparse.Namespace) -> dict:
    if visual.is_visual(args.demos):
        # the visual recipe builds on this module's state recipe: imported here, not at the top
        # (each imports the other)
        import perceive

        return perceive.train(args)
    torch.set_num_threads(TORCH_THREADS)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    observations, actions, bases, env_info = load_episodes(args.demos, args.num_demos)
    obs = np.concatenate([o[: len(a)] for o, a in zip(observations, actions, strict=True)])
    act_dim = actions[0].shape[1]
    frame = (np.zeros(act_dim, np.float32), np.zeros(act_dim, np.int64))
    env = dataset_env(env_info, args.layout, args.demos)
    try:
        if args.frame == "target":
            frame = target_frame(env, obs.shape[1], act_dim)
        anchors = [o[:, frame[1]] * frame[0] for o in observations]
        targets, valid = chunk_targets(actions, args.chunk, args.hold, anchors)
        flat = targets[:, 0]  # the step's own action (relative to its own anchor: the action)
        obs_std = obs.std(0)  # the scales: of the demonstrations alone
        act_std = targets.std(0)  # per step of the chunk and action: (chunk, A)
        demo_obs = obs
        obs, targets, valid = with_corrective_copies(
            args, env, (observations, actions, bases), obs, targets, valid, frame
        )
    finally:
        env.close()
    policy = ChunkPolicy(
        demo_obs.mean(0), np.where(obs_std < MIN_STD, 1.0, obs_std),
        keep_mask(args.drop, args.demos, obs.shape[1]), targets.mean(0),
        np.where(act_std < MIN_STD, 1.0, act_std), flat.min(0), flat.max(0),
        args.chunk, args.hidden, args.decay, frame,
    )  # fmt: skip
    x = policy.normalise(torch.from_numpy(obs))
    y = (torch.from_numpy(targets) - policy.act_mean) / policy.act_std
    mask = torch.from_numpy(valid).float()[:, :, None]

    def batch_loss(batch: torch.Tensor) -> torch.Tensor:
        inputs = x[batch]
        if args.obs_noise > 0:
            inputs = inputs + args.obs_noise * torch.randn_like(inputs) * policy.obs_keep
        err = (policy.raw_normalised(inputs) - y[batch]).abs() * mask[batch]
        return err.sum() / (mask[batch].sum() * y.shape[2])

    iters, loss, seconds = fit(policy, args, batch_loss, len(x), rng)
    kwargs = env_info.get("env_kwargs", {})
    info = {
        "demos": str(args.demos),
        "episodes": len(actions),
        "env_id": env_info.get("env_id"),
        "control_mode": kwargs.get("control_mode"),
        "layout_file": kwargs.get("layout_file"),
        "pairs": len(demo_obs),
        "pairs_with_copies": len(x),
        "obs_dim": int(x.shape[1]),
        "act_dim": int(flat.shape[1]),
        "chunk": args.chunk,
        "frame": args.frame,
        "target_joints": [int(j) for j, c in zip(frame[1], frame[0], strict=True) if c != 0],
        "decay": args.decay,
        "hidden": args.hidden,
        "drop": args.drop,
        "hold": args.hold,
        "obs_noise": args.obs_noise,
        "perturb": args.perturb,
        "perturb_copies": args.perturb_copies,
        "batch_size": args.batch_size,
        "lr": args.lr,
        "weight_decay": args.weight_decay,
        "seed": args.seed,
        "minutes": args.minutes,
        "iterations": iters,
        "final_loss": loss,
        "train_seconds": round(seconds, 1),
    }
    with atomic_output(args.out / "train.json") as tmp:
        tmp.write_text(json.dumps(info, indent=2) + "\n")
    return info


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--demos", type=Path, required=True,
                    help="a dataset (.h5): state observations train a state policy, camera "
                    "frames (--obs-mode rgb) a visual one")
    ap.add_argument("--out", type=Path, required=True, help="folder for policy.pt, train.json")
    ap.add_argument("--minutes", type=float, default=20.0, help="training time (wall clock)")
    ap.add_argument("--layout", type=Path, default=None,
                    help="the layout the demos were collected on, where the dataset's own "
                    "env_kwargs.layout_file is not on this machine")
    ap.add_argument("--num-demos", type=int, default=-1, help="episodes to load (-1: all)")
    ap.add_argument("--chunk", type=int, default=16, help="actions predicted per step")
    ap.add_argument("--decay", type=float, default=-0.1,
                    help="temporal ensembling: a prediction made j steps ago weighs "
                    "exp(-decay*j); negative: the older weigh more, as ACT's exp(-k*i), i from "
                    "the oldest")
    ap.add_argument("--frame", choices=["target", "action"], default="target",
                    help="target: a delta-joint controller's actions are predicted and ensembled "
                    "as the joint targets they set and run relative to the joints of the step "
                    "they run at; action: as the actions")
    ap.add_argument("--hidden", type=int, nargs="+", default=[256, 256],
                    help="the MLP's hidden widths")
    ap.add_argument("--drop", nargs="*", default=["qvel"], choices=["qpos", "qvel"],
                    help="the robot's joint state groups the policy does not see (default qvel)")
    ap.add_argument("--hold", action="store_true",
                    help="train the chunk's steps past an episode's end as its last action")
    ap.add_argument("--obs-noise", type=float, default=0.02,
                    help="training noise on the normalised observation (standard deviations)")
    ap.add_argument("--perturb", type=float, default=0.03,
                    help="corrective copies: the arm's joints moved by Gaussian offsets of this "
                    "many radians, the observation recomputed, the same joint targets (0: none)")
    ap.add_argument("--perturb-copies", type=int, default=1,
                    help="corrective copies of each demonstrated step")
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--weight-decay", type=float, default=1e-4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None,
                    help=f"torch threads (default: {TORCH_THREADS} for a state policy, "
                    f"{VISUAL_THREADS} for a visual one)")
    args = ap.parse_args(argv)
    if not args.demos.is_file() or not args.demos.with_suffix(".json").is_file():
        ap.error(f"{args.demos}: no such dataset (an .h5 with its .json beside it)")
    if args.chunk < 1 or args.minutes <= 0:
        ap.error("--chunk must be >= 1 and --minutes > 0")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    info = train(args)
    print(json.dumps(info, indent=2))
    print(
        f"evaluate: embodied-envs eval --policy {args.out / 'policy.pt'} --control-mode "
        f"{info['control_mode']} --layout LAYOUT --episodes 30 --seed 10000 --out OUT"
    )


if __name__ == "__main__":
    main()
