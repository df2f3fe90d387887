"""A visual policy with a perception bottleneck: an estimator reads the objects' positions from
the camera frame, and a state policy (``train_policy.ChunkPolicy``, with its corrective copies)
acts on the joints, the TCP, the goal and those estimates. No object pose is read at run time.

Trained end to end on actions alone, a pixel policy on 200 demonstrations replays them from the
joints and ignores where the object is (docs/evaluation.md); the state policy's corrective
copies, which taught it to re-grasp, move the arm and recompute the observation, which a frame
cannot be. Split in two, each half learns what it can from the same dataset:

- the **estimator** (``Estimator``: ``visual.Encoder``, a conv net ending in a spatial
  soft-argmax, then an MLP) maps the frame alone to the observation's ``PERCEIVED`` values: each
  mover slot's position and its vector to its goal, and the receptacle's position. Its labels are
  the state observation the env computes from the dataset's recorded env states
  (``flat_states``: privileged supervision, training only). Augmented with colour jitter and a
  shift of up to ``SHIFT_PX`` pixel; the rooms vary when the dataset was collected with
  ``--rooms``. The last ``HOLD_OUT`` of the episodes are kept out of its training and measure its
  error, in metres, on frames it never saw.
- the **policy** is the state recipe's ChunkPolicy over the state observation with the
  perceived values in place of the true ones (the TCP-to-mover vectors recomputed from them,
  ``PerceivingPolicy.assemble``), the orientations left out (a frame of a symmetric can does not
  tell its yaw), trained on the demonstrations and their corrective copies with the perceived
  values blurred by the estimator's held-out error per value: it learns to act on estimates as
  good as the estimator's.

The exported ``PerceivingPolicy`` takes ``(image, state)`` as ``visual.VisualChunkPolicy`` does
(``camera``, ``obs_keys``, ``image_hw``), ``state`` the leading groups of the state observation
(``STATE_KEYS``: the joints, the grasp flag, the TCP, the goal and the task kind), all in the
env's ``rgb`` observation.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import h5py
import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
import visual  # noqa: E402

from embodied_envs.envs.tasks import KIND_IDS  # noqa: E402

CAMERA_PARAMS = tuple(f"sensor_param/{visual.CAMERA}/{k}" for k in ("intrinsic_cv", "extrinsic_cv"))
KEYPOINT_WEIGHT = 1.0  # the estimator's keypoint loss (each object's pixel) against its values'
# the rgb observation's groups that lead the state observation, in its order
STATE_KEYS = ("agent/qpos", "agent/qvel", "extra/is_grasped", "extra/tcp_pose",
              "extra/goal_pos", "extra/task_kind")  # fmt: skip
POS, POSE = 3, 7
SHIFT_PX = 1  # the estimator's random shift: the camera is fixed, a position is its pixels
RENDER_SEED = 1 << 24  # the extra frames' seeds: past any collect or eval seed range in use
RENDER_SHARE = 0.25  # of --minutes: rendering the extra frames
RENDER_SIGMA = 0.05  # rad: the extra frames' arm, off a demonstrated configuration
HOLD_OUT = 0.1  # the share of episodes that measure the estimator (at least one)
ESTIMATOR_SHARE = 0.5  # of --minutes: the estimator's training; the rest the policy's
HIDDEN = 256  # the estimator's MLP
MIN_STD = 1e-3  # a perceived value varying less than this over the dataset is a constant


def slots(slices: dict[str, slice]) -> int:
    return (slices["mover_pose"].stop - slices["mover_pose"].start) // POSE


def perceived_index(slices: dict[str, slice]) -> np.ndarray:
    """The state observation's values the estimator reads from the frame: every mover slot's
    position, its vector to its goal, the receptacle's position."""
    m = slots(slices)
    origins = [slices["mover_pose"].start + POSE * s + k for s in range(m) for k in range(POS)]
    to_goal = list(range(slices["mover_to_goal_pos"].start, slices["mover_to_goal_pos"].stop))
    rec = [slices["receptacle_pose"].start + k for k in range(POS)]
    return np.array(origins + to_goal + rec, np.int64)


def to_goal_positions(slices: dict[str, slice]) -> np.ndarray:
    """Where the movers' vectors to their goals are among the perceived values."""
    m = slots(slices)
    return np.arange(m * POS, 2 * m * POS)


def perceived_names(slices: dict[str, slice]) -> list[str]:
    """Per perceived value (``perceived_index``'s order), its name."""
    m, axes = slots(slices), "xyz"
    return ([f"mover {s} {a}" for s in range(m) for a in axes]
            + [f"mover {s} to goal {a}" for s in range(m) for a in axes]
            + [f"receptacle {a}" for a in axes])  # fmt: skip


def keypoint_points(flats: np.ndarray, slices: dict[str, slice]) -> tuple[np.ndarray, np.ndarray]:
    """The objects whose pixels the estimator's first keypoints are asked for, per state
    observation ``(N, D)``: every mover slot's origin, then the receptacle's ``(N, K, 3)``, and
    which are there ``(N, K)`` (the slot and receptacle masks)."""
    m = slots(slices)
    movers = flats[:, slices["mover_pose"]].reshape(len(flats), m, POSE)[:, :, :POS]
    rec = flats[:, slices["receptacle_pose"]][:, None, :POS]
    there = np.concatenate([flats[:, slices["mover_mask"]], flats[:, slices["receptacle_mask"]]], 1)
    return np.concatenate([movers, rec], 1), there > 0.5


def orientation_index(slices: dict[str, slice]) -> np.ndarray:
    """The movers' and the receptacle's quaternions: what the policy does not see."""
    m = slots(slices)
    quats = [slices["mover_pose"].start + POSE * s + k for s in range(m) for k in range(POS, POSE)]
    return np.array(quats + [slices["receptacle_pose"].start + k for k in range(POS, POSE)])


def flat_states(env, path: Path, episodes: list[dict]) -> tuple[list, list, list]:
    """Per episode its state observations ``(T+1, D)``, as ``env`` (``obs_mode="state_dict"``)
    computes them from the recorded env states (the groups the rgb observation holds, its
    ``STATE_KEYS``, the grasp flag among them: contacts need a step, are the recorded ones), its
    actions ``(T, A)`` and the robot's recorded base poses ``(T+1, 7)``."""
    from mani_skill.trajectory.utils import index_dict  # the env's process only
    from mani_skill.utils.common import flatten_state_dict

    def load(group):
        return {k: load(v) if isinstance(v, h5py.Group) else np.asarray(v)
                for k, v in group.items()}  # fmt: skip

    out, actions, bases, u = [], [], [], env.unwrapped
    robot = u.agent.robot.name
    with h5py.File(path, "r") as f:
        for ep in episodes:
            traj = f[f"traj_{ep['episode_id']}"]
            if "env_states" not in traj:
                sys.exit(f"{path}: traj_{ep['episode_id']} has no env_states (the labels of the "
                         "visual recipe's estimator). Fix: collect with embodied-envs collect, "
                         "which records them")  # fmt: skip
            states = load(traj["env_states"])
            steps = len(traj["actions"]) + 1
            rows = []
            for i in range(steps):
                u.set_state_dict(index_dict(states, i))
                rows.append(np.asarray(flatten_state_dict(u.get_obs(), use_torch=True)[0]))
            flat = np.stack(rows).astype(np.float32)
            lead = np.concatenate([np.asarray(traj[f"obs/{k}"], np.float32).reshape(steps, -1)
                                   for k in STATE_KEYS], 1)  # fmt: skip
            flat[:, : lead.shape[1]] = lead
            out.append(flat)
            actions.append(np.asarray(traj["actions"], np.float32))
            bases.append(states["articulations"][robot][:, :POSE])
    return out, actions, bases


def load_frames(path: Path, episodes: list[dict]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per episode its camera frames ``(T+1, H, W, 3)`` uint8 and the camera's projection
    matrices ``(T+1, 3, 4)`` (intrinsics times extrinsics); one line naming a missing key."""
    frames, cameras = [], []
    need = (f"sensor_data/{visual.CAMERA}/rgb", *CAMERA_PARAMS, *STATE_KEYS)
    with h5py.File(path, "r") as f:
        for ep in episodes:
            obs = f[f"traj_{ep['episode_id']}/obs"]
            missing = [k for k in need if k not in obs]
            if missing:
                sys.exit(f"{path}: traj_{ep['episode_id']} has no obs/{missing[0]}. Fix: collect "
                         "with --obs-mode rgb (a visual policy needs the camera frames and "
                         "parameters, the joints, the grasp flag and the goal)")  # fmt: skip
            frames.append(np.asarray(obs[f"sensor_data/{visual.CAMERA}/rgb"], np.uint8))
            cameras.append(projection(*(np.asarray(obs[k], np.float32) for k in CAMERA_PARAMS)))
    return frames, cameras


def projection(intrinsic: np.ndarray, extrinsic: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` OpenCV intrinsics and ``(N, 3, 4)`` extrinsics -> ``(N, 3, 4)``."""
    return (intrinsic @ extrinsic).astype(np.float32)


def pixel_targets(points: np.ndarray, camera: np.ndarray, hw: tuple[int, int]):
    """World points ``(N, K, 3)`` seen by cameras ``(N, 3, 4)`` -> their places in the
    soft-argmax's coordinates ``(N, K, 2)`` (``visual.SpatialSoftArgmax`` over the encoder's
    maps, a quarter of the frame's size: -1 and 1 the first and last map cells' centres) and
    whether each is in front of the camera and inside the frame ``(N, K)``."""
    homog = np.concatenate([points, np.ones_like(points[..., :1])], -1)
    uvw = np.einsum("nij,nkj->nki", camera, homog)
    depth = uvw[..., 2]
    uv = uvw[..., :2] / np.where(np.abs(depth) < 1e-6, 1e-6, depth)[..., None]
    size = np.array([hw[1], hw[0]], np.float32)  # (x, y)
    cells = size / 4
    coords = ((uv - 1.5) / 4) / (cells - 1) * 2 - 1  # a pixel's centre at integer u: OpenCV's
    inside = (depth > 0) & (uv >= 0).all(-1) & (uv <= size - 1).all(-1)
    return coords.astype(np.float32), inside


class Estimator(nn.Module):
    """``(B, H, W, 3)`` uint8 frames -> the perceived values ``(B, P)``, in the observation's
    units; ``mean`` and ``std`` are the dataset's (a value whose ``std`` is under ``MIN_STD`` is
    that constant)."""

    def __init__(self, image_hw: tuple[int, int], mean: np.ndarray, std: np.ndarray):
        super().__init__()
        self.encoder = visual.Encoder(image_hw)
        self.mlp = nn.Sequential(
            nn.Linear(self.encoder.width, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
            nn.Linear(HIDDEN, len(mean)),
        )  # fmt: skip
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(np.where(std < MIN_STD, 1.0, std),
                                                     dtype=torch.float32))  # fmt: skip
        # a value that never varies in the dataset (an empty slot) is its constant, not a guess
        self.register_buffer("vary", torch.as_tensor(std > MIN_STD, dtype=torch.float32))

    def normalised(self, image: torch.Tensor) -> torch.Tensor:
        """``(B, 3, H, W)`` float frames in [0, 1] -> normalised estimates."""
        return self.heads(image)[0]

    def heads(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The normalised estimates and the encoder's keypoints ``(B, KEYPOINTS, 2)`` (training
        asks keypoint ``k`` for the ``k``-th object's pixel: ``keypoint_points``)."""
        features = self.encoder(image)
        k = visual.KEYPOINTS
        points = torch.stack([features[:, :k], features[:, k : 2 * k]], -1)
        return self.mlp(features), points

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        x = image.permute(0, 3, 1, 2).float() / 255.0
        return self.normalised(x) * self.std * self.vary + self.mean


class PerceivingPolicy(nn.Module):
    """``(image, state)`` -> the state policy's action on the state observation assembled from
    ``state`` (its leading groups) and the estimator's values."""

    def __init__(self, estimator: Estimator, policy: nn.Module, template: np.ndarray,
                 slices: dict[str, slice], image_hw: tuple[int, int]):  # fmt: skip
        super().__init__()
        self.estimator, self.policy = estimator, policy
        self.camera, self.obs_keys = visual.CAMERA, list(STATE_KEYS)
        self.image_hw = [int(image_hw[0]), int(image_hw[1])]
        self.lead = slices["task_kind"].stop  # the state input's width
        m = slots(slices)
        origins = perceived_index(slices)[: m * POS]
        tcp, to_mover = slices["tcp_pose"].start, slices["tcp_to_mover_pos"]
        to_goal, goal = slices["mover_to_goal_pos"], slices["goal_pos"].start
        self.pick = slices["task_kind"].start + KIND_IDS["pick"]  # its one-hot column
        for name, value in dict(
            template=torch.as_tensor(template, dtype=torch.float32),
            perceived=torch.as_tensor(perceived_index(slices)),
            origins=torch.as_tensor(origins),
            tcp=torch.arange(tcp, tcp + POS),
            to_mover=torch.arange(to_mover.start, to_mover.stop),
            to_goal=torch.arange(to_goal.start, to_goal.stop),
            goal=torch.arange(goal, goal + POS),
            mask=torch.as_tensor(template[slices["mover_mask"]], dtype=torch.float32),
        ).items():  # fmt: skip
            self.register_buffer(name, value)

    def assemble(self, state: torch.Tensor, perceived: torch.Tensor) -> torch.Tensor:
        """The state observation ``(B, D)``: ``state``'s groups, the layout's constants
        (``template``), the ``perceived`` values, and computed from them as the env computes
        them: the TCP-to-mover vectors and, in a pick task (whose goal no frame shows), the
        movers' vectors to the goal."""
        b = state.shape[0]
        flat = self.template.expand(b, -1).clone()
        flat[:, : self.lead] = state
        flat[:, self.perceived] = perceived
        origin = flat[:, self.origins].view(b, -1, 3)  # positions
        tcp = state[:, self.tcp]
        live = self.mask[None, :, None]
        flat[:, self.to_mover] = ((origin - tcp[:, None]) * live).view(b, -1)
        pick = state[:, self.pick].view(b, 1, 1)
        seen = flat[:, self.to_goal].view(b, -1, 3)
        picked = (state[:, self.goal][:, None] - origin) * live
        flat[:, self.to_goal] = (pick * picked + (1.0 - pick) * seen).view(b, -1)
        return flat

    @torch.jit.export
    def reset(self) -> None:
        self.policy.reset()

    def forward(self, image: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        return self.policy(self.assemble(state, self.estimator(image)))


def constant_template(flats: list[np.ndarray], slices: dict[str, slice], path: Path) -> np.ndarray:
    """The state observation's values that no frame shows and that stay fixed over the dataset
    (the mover and receptacle masks, the receptacle's geometry), others zero; one line where
    they vary (episodes of different tasks: one estimator per task)."""
    rows = np.concatenate(flats)
    template = np.zeros(rows.shape[1], np.float32)
    for key in ("mover_mask", "receptacle_geometry", "receptacle_mask"):
        part = rows[:, slices[key]]
        if np.ptp(part, 0).max() > 1e-6:
            sys.exit(f"{path}: the episodes' {key} differ (tasks of several layouts); the visual "
                     "recipe learns one task. Fix: collect the dataset on one layout")  # fmt: skip
        template[slices[key]] = part[0]
    return template


def rendered_frames(
    camera_env, state_env, seconds: float, joints: np.ndarray, sigma: float, rng
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """More frames for the estimator, rendered for ``seconds`` of wall clock: ``camera_env``
    (the dataset's env and camera flags) reset by seeds from ``RENDER_SEED`` up (a placement and
    a room no demonstration or evaluation draws), the arm set to a demonstrated configuration
    (a row of ``joints``, moved by Gaussian offsets of ``sigma`` radians, within the joints'
    limits), its camera's frame, and the state observation ``state_env`` computes there.
    Returns the frames ``(N, H, W, 3)``, the cameras' projections ``(N, 3, 4)`` and the state
    observations ``(N, D)``."""
    from mani_skill.utils.common import flatten_state_dict  # the env's process only

    frames, cameras, flats = [], [], []
    cam, state = camera_env.unwrapped, state_env.unwrapped
    limits = cam.agent.robot.get_qlimits()[0].cpu().numpy()
    start = time.perf_counter()
    while not frames or time.perf_counter() - start < seconds:  # one at least
        camera_env.reset(seed=RENDER_SEED + len(frames))
        q = joints[rng.integers(len(joints))] + rng.normal(0.0, sigma, joints.shape[1])
        q = np.clip(q, limits[:, 0], limits[:, 1])
        cam.agent.robot.set_qpos(torch.as_tensor(q[None], dtype=torch.float32))
        obs = cam.get_obs()
        frames.append(np.asarray(obs["sensor_data"][visual.CAMERA]["rgb"][0], np.uint8))
        param = obs["sensor_param"][visual.CAMERA]
        cameras.append(projection(*(np.asarray(param[k.rsplit("/", 1)[1]][0])
                                    for k in CAMERA_PARAMS)))  # fmt: skip
        state.set_state_dict(cam.get_state_dict())
        flats.append(np.asarray(flatten_state_dict(state.get_obs(), use_torch=True)[0]))
    return np.stack(frames), np.stack(cameras), np.stack(flats).astype(np.float32)


@torch.no_grad()
def estimate(estimator: Estimator, images: torch.Tensor, batch: int = 512) -> torch.Tensor:
    estimator.eval()
    out = torch.cat([estimator(images[i : i + batch]) for i in range(0, len(images), batch)])
    estimator.train()
    return out
