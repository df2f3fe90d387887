"""The visual recipe: a policy with a perception bottleneck. An estimator reads the objects'
positions from the camera frame, and a state policy (``train_policy.ChunkPolicy``, with its
corrective copies) acts on the joints, the TCP, the goal and those estimates. No object pose is
read at run time.

Trained end to end on actions alone, a pixel policy on 200 demonstrations replays them from the
joints and ignores where the object is (docs/evaluation.md); the state policy's corrective
copies, which taught it to re-grasp, move the arm and recompute the observation, which a frame
cannot be. Split in two, each half learns what it can:

- the **estimator** (``Estimator``: ``visual.Encoder``, a conv net ending in a spatial
  soft-argmax, then an MLP) maps the frame alone to the perceived values (``perceived_index``):
  each mover slot's position and its vector to its goal, and the receptacle's position. Its
  labels are the state observation the env computes from the recorded env states
  (``flat_states``: privileged supervision, training only). Its frames are the demonstrations'
  and frames rendered through the env (``rendered_frames``: other placements and rooms, the arm
  near a demonstrated configuration; 200 demonstrations show 200 placements only). Its first
  keypoints are asked for each object's pixel (the camera's projection of its position,
  ``pixel_targets``), which a convolution finds wherever the object stands. Augmented with
  colour jitter and a shift of up to ``SHIFT_PX`` pixel. The last ``HOLD_OUT`` of the episodes
  are kept out of its training and measure its error on frames it never saw.
- the **policy** is the state recipe's ChunkPolicy over the state observation with the
  perceived values in place of the true ones, the TCP-to-mover vectors and a pick's vectors to
  its goal (a goal no frame shows) computed from them (``PerceivingPolicy.assemble``), the
  orientations left out (a frame of a can does not tell its yaw). It is trained on the true
  state of the demonstrations and their corrective copies (trained on states blurred by the
  estimator's error instead, it became imprecise: docs/evaluation.md).

The exported ``PerceivingPolicy`` takes ``(image, state)``: ``image`` the camera's
``(B, H, W, 3)`` uint8 frame, ``state`` the leading groups of the state observation
(``STATE_KEYS``: the joints, the grasp flag, the TCP, the goal and the task kind), all in the
env's ``rgb`` observation; ``embodied-envs eval`` reads its ``camera``, ``obs_keys`` and
``image_hw`` attributes to build them.

Its share of ``--minutes``: rendering ``RENDER_SHARE``, the estimator ``ESTIMATOR_SHARE``, the
policy the rest.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "make"))
import make_rooms  # noqa: E402
import perturb  # noqa: E402
import train_policy as tp  # noqa: E402
import visual  # noqa: E402

from embodied_envs.envs.tasks import KIND_IDS  # noqa: E402
from embodied_envs.paths import atomic_output  # noqa: E402

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
SWAP_ROOMS = 48  # random rooms (make_rooms.random_style) the estimator's background swaps draw
ROOMS_SHARE = 0.1  # of the rendering share: at most this long rendering them
SWAP_GAUSSIANS = 20_000  # per random room
SWAP_SHARE = 0.5  # of the estimator's frames per batch: their room swapped for a random one
MIN_MATCH = 0.2  # a frame sharing fewer of its pixels with every known room keeps its own


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
    units; ``mean`` and ``std`` are the dataset's (a value whose ``std`` is under
    ``train_policy.MIN_STD`` is that constant)."""

    def __init__(self, image_hw: tuple[int, int], mean: np.ndarray, std: np.ndarray):
        super().__init__()
        self.encoder = visual.Encoder(image_hw)
        self.mlp = nn.Sequential(
            nn.Linear(self.encoder.width, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
            nn.Linear(HIDDEN, len(mean)),
        )  # fmt: skip
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(np.where(std < tp.MIN_STD, 1.0, std),
                                                     dtype=torch.float32))  # fmt: skip
        # a value that never varies in the dataset (an empty slot) is its constant, not a guess
        self.register_buffer("vary", torch.as_tensor(std > tp.MIN_STD, dtype=torch.float32))

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
    camera_env, state_env, seconds: float, joints: np.ndarray, sigma: float, rng, least: int = 1,
    first: int = RENDER_SEED,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """More frames for the estimator, rendered for ``seconds`` of wall clock: ``camera_env``
    (the dataset's env and camera flags) reset by seeds from ``first`` up (a placement and
    a room no demonstration or evaluation draws), the arm set to a demonstrated configuration
    (a row of ``joints``, moved by Gaussian offsets of ``sigma`` radians, within the joints'
    limits), its camera's frame, and the state observation ``state_env`` computes there; at
    least ``least`` frames.
    Returns the frames ``(N, H, W, 3)``, the cameras' projections ``(N, 3, 4)`` and the state
    observations ``(N, D)``."""
    from mani_skill.utils.common import flatten_state_dict  # the env's process only

    frames, cameras, flats = [], [], []
    cam, state = camera_env.unwrapped, state_env.unwrapped
    limits = cam.agent.robot.get_qlimits()[0].cpu().numpy()
    start = time.perf_counter()
    while len(frames) < least or time.perf_counter() - start < seconds:
        camera_env.reset(seed=first + len(frames))
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


def sensor_view(env):
    """``env``'s camera as the splat renderer takes it (after a reset)."""
    from embodied_envs.splat.camera import PinholeCamera  # the env's process only

    sensor = env.unwrapped.scene.sensors[visual.CAMERA]
    return PinholeCamera.from_opengl(
        sensor.camera.get_model_matrix()[0].cpu().numpy().astype(np.float64),
        sensor.camera.get_intrinsic_matrix()[0].cpu().numpy().astype(np.float64),
        sensor.config.width, sensor.config.height,
    )  # fmt: skip


def room_views(env) -> torch.Tensor:
    """What ``env``'s camera shows of each room of its pool (without one, its layout's room)
    with nothing in front: ``(K, H, W, 3)`` uint8, rendered by the env's own splat renderer."""
    u = env.unwrapped
    env.reset(seed=RENDER_SEED)
    camera, rooms = sensor_view(env), u.room_pool or u.hybrid.rooms[:1]
    return torch.stack([u.hybrid.render_one(camera, u.hybrid.poses[0], room)[0].cpu()
                        for room in rooms])  # fmt: skip


def random_rooms(env, seconds: float, rng) -> torch.Tensor:
    """Rooms drawn from the whole style space (``make_rooms.random_style``) as ``env``'s camera
    sees them, rendered by its splat renderer: ``(R, H, W, 3)`` uint8, ``SWAP_ROOMS`` or as many
    as ``seconds`` allow (at least one)."""
    u = env.unwrapped
    env.reset(seed=RENDER_SEED)
    camera, out, start = sensor_view(env), [], time.perf_counter()
    while not out or (len(out) < SWAP_ROOMS and time.perf_counter() - start < seconds):
        style = make_rooms.random_style(rng)
        room = Path(f"random_room_{len(out)}")
        u.hybrid.add_room(room, make_rooms.room_splat(style, SWAP_GAUSSIANS))
        out.append(u.hybrid.render_one(camera, u.hybrid.poses[0], room)[0].cpu())
    return torch.stack(out)


@torch.no_grad()
def estimate(estimator: Estimator, images: torch.Tensor, batch: int = 512) -> torch.Tensor:
    estimator.eval()
    out = torch.cat([estimator(images[i : i + batch]) for i in range(0, len(images), batch)])
    estimator.train()
    return out


def train(args: argparse.Namespace) -> dict:
    """A visual policy with a perception bottleneck (``py``) from a dataset with
    camera frames: the estimator, then the state policy on its estimates."""
    torch.set_num_threads(args.threads or tp.VISUAL_THREADS)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    generator = torch.Generator().manual_seed(args.seed)
    meta = json.loads(args.demos.with_suffix(".json").read_text())
    episodes = meta["episodes"][: args.num_demos if args.num_demos > 0 else None]
    if not episodes:
        sys.exit(f"{args.demos}: no episodes")
    env_info = meta["env_info"]
    frames, cameras = load_frames(args.demos, episodes)
    env = tp.dataset_env(env_info, args.layout, args.demos)
    try:
        slices = perturb.obs_slices(env)
        flats, actions, bases = flat_states(env, args.demos, episodes)
        act_dim = actions[0].shape[1]
        frame = (np.zeros(act_dim, np.float32), np.zeros(act_dim, np.int64))
        if args.frame == "target":
            frame = tp.target_frame(env, flats[0].shape[1], act_dim)
        anchors = [o[:, frame[1]] * frame[0] for o in flats]
        targets, valid = tp.chunk_targets(actions, args.chunk, args.hold, anchors)
        obs = np.concatenate([o[: len(a)] for o, a in zip(flats, actions, strict=True)])
        obs_std, act_std, flat = obs.std(0), targets.std(0), targets[:, 0]
        demo_obs = obs
        obs, targets, valid = tp.with_corrective_copies(
            args, env, (flats, actions, bases), obs, targets, valid, frame
        )
        # the estimator: every frame of the episodes but the held-out ones, and frames rendered
        # through the env at other placements and rooms, to their perceived values
        held = max(1, round(HOLD_OUT * len(episodes))) if len(episodes) > 1 else 0
        learn = slice(0, len(episodes) - held)
        started = time.perf_counter()
        # background swaps: the frames' rooms (known) replaced by random ones; hybrid frames only
        hybrid = bool(env_info["env_kwargs"].get("hybrid_obs", False))
        camera_env = tp.dataset_env(env_info, args.layout, args.demos,
                                 env_info["env_kwargs"].get("obs_mode", "rgb"))  # fmt: skip
        try:
            known = room_views(camera_env) if hybrid else None
            budget = ROOMS_SHARE * RENDER_SHARE * args.minutes * 60
            swaps = random_rooms(camera_env, budget, rng) if hybrid else None
            more_frames, more_cameras, more_flats = rendered_frames(
                camera_env, env, RENDER_SHARE * args.minutes * 60 - (time.perf_counter() - started),
                np.concatenate(flats[learn])[:, slices["qpos"]], RENDER_SIGMA, rng,
            )  # fmt: skip
        finally:
            camera_env.close()
    finally:
        env.close()
    template = constant_template(flats, slices, args.demos)
    seen = perceived_index(slices)
    images = torch.from_numpy(np.concatenate([*frames[learn], more_frames]))
    seen_flats = np.concatenate([*flats[learn], more_flats])
    labels = torch.from_numpy(seen_flats[:, seen])
    # the first keypoints: each object's pixel, where it is there and in the frame
    points, there = keypoint_points(seen_flats, slices)
    pixels, inside = pixel_targets(
        points, np.concatenate([*cameras[learn], more_cameras]), tuple(images.shape[1:3])
    )
    pixels, shown = torch.from_numpy(pixels), torch.from_numpy(there & inside).float()[..., None]
    masks = visual.foreground_masks(images, known, MIN_MATCH) if hybrid else None
    swap_rgb = swaps.permute(0, 3, 1, 2).float() / 255.0 if hybrid else None
    # a pick goal is in no frame: its vectors are computed from the estimates (assemble)
    weight = torch.ones(len(seen))
    if (seen_flats[:, slices["task_kind"].start + KIND_IDS["pick"]] > 0.5).all():
        weight[to_goal_positions(slices)] = 0.0
    estimator = Estimator(
        tuple(images.shape[1:3]), labels.mean(0).numpy(), labels.std(0).numpy()
    )
    y = (labels - estimator.mean) / estimator.std

    def estimator_loss(batch: torch.Tensor) -> torch.Tensor:
        image = images[batch].permute(0, 3, 1, 2).float() / 255.0
        if swap_rgb is not None:
            image = visual.swap_backgrounds(image, masks[batch], swap_rgb, generator, SWAP_SHARE)
        image = visual.augment(image, generator, SHIFT_PX)
        guess, keys = estimator.heads(image)
        values = ((guess - y[batch]).abs() * weight).sum() / (weight.sum() * len(batch))
        off = (keys[:, : pixels.shape[1]] - pixels[batch]).abs() * shown[batch]
        return values + KEYPOINT_WEIGHT * off.sum() / shown[batch].sum().clamp(min=1)

    render_seconds = time.perf_counter() - started
    share = ESTIMATOR_SHARE * args.minutes
    est_iters, est_loss, est_seconds = tp.fit(estimator, args, estimator_loss, len(images), rng,
                                           share, save=False, name="estimator ")  # fmt: skip
    for p in estimator.parameters():
        p.requires_grad_(False)
    vary = estimator.vary.numpy() > 0
    error = np.zeros(len(seen), np.float32)  # the held-out RMS error per perceived value
    if held:
        hold_images = torch.from_numpy(np.concatenate(frames[learn.stop :]))
        truth = np.concatenate(flats[learn.stop :])[:, seen]
        miss = estimate(estimator, hold_images).numpy() - truth
        error = np.sqrt((miss**2).mean(0))
    keep = tp.keep_mask(args.drop, args.demos, obs.shape[1], slices)
    keep[orientation_index(slices)] = 0.0
    policy = tp.ChunkPolicy(
        demo_obs.mean(0), np.where(obs_std < tp.MIN_STD, 1.0, obs_std), keep, targets.mean(0),
        np.where(act_std < tp.MIN_STD, 1.0, act_std), flat.min(0), flat.max(0),
        args.chunk, args.hidden, args.decay, frame,
    )  # fmt: skip
    composite = PerceivingPolicy(estimator, policy, template, slices, images.shape[1:3])
    x = torch.from_numpy(obs)
    target = (torch.from_numpy(targets) - policy.act_mean) / policy.act_std
    mask = torch.from_numpy(valid).float()[:, :, None]
    state, truth_t = x[:, : composite.lead], x[:, torch.from_numpy(seen)]

    def policy_loss(batch: torch.Tensor) -> torch.Tensor:
        inputs = policy.normalise(composite.assemble(state[batch], truth_t[batch]))
        if args.obs_noise > 0:
            noise = torch.randn(inputs.shape, generator=generator)
            inputs = inputs + args.obs_noise * noise * policy.obs_keep
        err = (policy.raw_normalised(inputs) - target[batch]).abs() * mask[batch]
        return err.sum() / (mask[batch].sum() * target.shape[2])

    own = (1.0 - RENDER_SHARE - ESTIMATOR_SHARE) * args.minutes  # at least
    rest = max(args.minutes - (time.perf_counter() - started) / 60, own)
    iters, loss, seconds = tp.fit(policy, args, policy_loss, len(x), rng, rest,
                               export=composite, name="policy ")  # fmt: skip
    live = [i for i, v in enumerate(vary) if v and weight[i] > 0]
    names = perceived_names(slices)
    kwargs = env_info.get("env_kwargs", {})
    info = {
        "demos": str(args.demos), "episodes": len(actions), "env_id": env_info.get("env_id"),
        "kind": "visual", "obs_mode": kwargs.get("obs_mode"),
        "control_mode": kwargs.get("control_mode"), "layout_file": kwargs.get("layout_file"),
        "camera": visual.CAMERA, "image_hw": list(images.shape[1:3]),
        "state_keys": list(STATE_KEYS), "hybrid_obs": kwargs.get("hybrid_obs", False),
        "rooms": kwargs.get("rooms"), "robot_visual_faces": kwargs.get("robot_visual_faces"),
        "estimator_episodes": learn.stop, "held_out_episodes": held,
        "rendered_frames": len(more_frames), "render_seconds": round(render_seconds, 1),
        "swap_rooms": 0 if swaps is None else len(swaps),
        "swappable_frames": 0 if masks is None else round(float((~masks).any((1, 2))
                                                                .float().mean()), 3),
        "estimator_iterations": est_iters, "estimator_loss": est_loss,
        "estimator_seconds": round(est_seconds, 1),
        "held_out_error_m": {names[i]: round(float(error[i]), 4) for i in live},
        "pairs": len(demo_obs), "pairs_with_copies": len(x), "act_dim": act_dim,
        "chunk": args.chunk, "frame": args.frame, "decay": args.decay, "hidden": args.hidden,
        "hold": args.hold, "obs_noise": args.obs_noise, "perturb": args.perturb,
        "perturb_copies": args.perturb_copies, "batch_size": args.batch_size, "lr": args.lr,
        "weight_decay": args.weight_decay, "seed": args.seed, "minutes": args.minutes,
        "threads": torch.get_num_threads(), "iterations": iters, "final_loss": loss,
        "train_seconds": round(time.perf_counter() - started, 1),
    }  # fmt: skip
    with atomic_output(args.out / "train.json") as tmp:
        tmp.write_text(json.dumps(info, indent=2) + "\n")
    return info
