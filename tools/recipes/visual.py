"""The visuomotor half of ``train_policy.py``: a policy from camera frames, the robot's joints
and the task's goal (no object poses), trained by behaviour cloning with action chunking and
run with the state recipe's temporal ensembling (``ensemble.TemporalEnsemble``).

The encoder is a small convolutional net over the ``base_camera``'s RGB frame ending in a
spatial soft-argmax (each of ``KEYPOINTS`` feature maps gives its expected image position, as
robomimic's and diffusion policy's image encoders do: positions are what a grasp needs) and the
maps' means; its features, with the normalised proprioception (``agent/qpos``,
``extra/tcp_pose``) and goal (``extra/goal_pos``), feed an MLP that predicts the next ``chunk``
actions. Training augments each frame with a random shift of up to ``SHIFT_PX`` pixels (DrQ's
augmentation) and colour jitter (brightness, contrast, per-channel gain); rooms differ between
episodes when the dataset was collected with ``--rooms``.

Trained on actions alone, the policy learns to replay its demonstrations from the joints and
the goal and ignores where the object is in the frame (on unseen starts its hand went to where
the object was in training). So training also asks the encoder, from the frame alone, for the
first mover's position relative to the hand and in the world (an auxiliary head, weight
``AUX_WEIGHT``; the positions come from the dataset's recorded env states, which ManiSkill's
datasets hold: privileged supervision at training time only). The policy itself never reads
an object's pose: at run time it sees the frame, the joints, the TCP pose and the goal.

The exported module takes ``(image, state)``: ``image`` the camera's ``(B, H, W, 3)`` uint8
frame, ``state`` the concatenation of the groups named by its ``obs_keys``; ``embodied-envs
eval`` reads its ``camera``, ``obs_keys`` and ``image_hw`` attributes to build them from the
env's observation.
"""

from __future__ import annotations

import sys
from pathlib import Path

import h5py
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ensemble import TemporalEnsemble  # noqa: E402

CAMERA = "base_camera"  # the env's sensor camera
STATE_KEYS = ("agent/qpos", "extra/tcp_pose", "extra/goal_pos")  # what the policy reads
KEYPOINTS = 32  # spatial soft-argmax keypoints
CHANNELS = (16, 32, 32)  # the conv layers' widths (wider: 4x the training time on 2 cores)
SHIFT_PX = 4  # random shift augmentation, pixels each way
BRIGHTNESS, CONTRAST, GAIN = 0.2, 0.2, 0.1  # colour jitter: relative ranges
AUX_DIM = 6  # the auxiliary target: the first mover's position relative to the TCP, and world
AUX_WEIGHT = 1.0  # its L1 loss's weight against the actions' (both on normalised values)
AUX_HIDDEN = 64


def is_visual(path: Path) -> bool:
    """Whether the dataset's observations hold camera frames (``sensor_data/.../rgb``)."""
    with h5py.File(path, "r") as f:
        names = [k for k in f.keys() if k.startswith("traj_")]
        if not names:
            return False
        obs = f[names[0]].get("obs")
        return isinstance(obs, h5py.Group) and f"sensor_data/{CAMERA}/rgb" in obs


def load_visual_episodes(
    path: Path, episodes: list[dict], mover: str | None = None
) -> tuple[list, list, list, list]:
    """Per episode its frames ``(T+1, H, W, 3)`` uint8, states ``(T+1, D)`` (``STATE_KEYS``),
    actions ``(T, A)`` and auxiliary targets ``(T+1, AUX_DIM)`` (the recorded actor ``mover``'s
    position less the TCP's, and its position; NaN where the episode has no such actor);
    exits with one line naming what a dataset lacks."""
    frames, states, actions, aux = [], [], [], []
    with h5py.File(path, "r") as f:
        for ep in episodes:
            traj = f[f"traj_{ep['episode_id']}"]
            obs = traj["obs"]
            missing = [k for k in (f"sensor_data/{CAMERA}/rgb", *STATE_KEYS) if k not in obs]
            if missing:
                sys.exit(
                    f"{path}: traj_{ep['episode_id']} has no obs/{missing[0]}. Fix: collect "
                    "with --obs-mode rgb (a visual policy needs the camera frames, the joints "
                    "and the goal)"
                )
            frames.append(np.asarray(obs[f"sensor_data/{CAMERA}/rgb"], np.uint8))
            states.append(np.concatenate(
                [np.asarray(obs[k], np.float32).reshape(len(frames[-1]), -1) for k in STATE_KEYS],
                1))  # fmt: skip
            actions.append(np.asarray(traj["actions"], np.float32))
            target = np.full((len(frames[-1]), AUX_DIM), np.nan, np.float32)
            actors = traj.get("env_states/actors")
            if mover is not None and actors is not None and mover in actors:
                where = np.asarray(actors[mover][:, :3], np.float32)
                tcp = np.asarray(obs["extra/tcp_pose"][:, :3], np.float32)
                target = np.concatenate([where - tcp, where], 1)
            aux.append(target)
    return frames, states, actions, aux


class SpatialSoftArgmax(nn.Module):
    """``(B, C, H, W)`` feature maps -> ``(B, 2C)``: each map's expected (x, y) in [-1, 1]."""

    def __init__(self, height: int, width: int):
        super().__init__()
        ys, xs = torch.meshgrid(
            torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij"
        )
        self.register_buffer("xs", xs.reshape(-1))
        self.register_buffer("ys", ys.reshape(-1))

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        b, c = maps.shape[0], maps.shape[1]
        weights = torch.softmax(maps.reshape(b, c, -1), -1)
        return torch.cat([(weights * self.xs).sum(-1), (weights * self.ys).sum(-1)], 1)


class Encoder(nn.Module):
    """``(B, 3, H, W)`` float frames in [0, 1] -> ``(B, width)`` features: a conv net
    (``CHANNELS``, two stride-2 layers), ``KEYPOINTS`` maps' spatial soft-argmax positions and
    the last layer's channel means."""

    def __init__(self, image_hw: tuple[int, int]):
        super().__init__()
        layers: list[nn.Module] = []
        size = 3
        for k, width in enumerate(CHANNELS):
            layers += [nn.Conv2d(size, width, 3, stride=2 if k < 2 else 1, padding=1), nn.ReLU()]
            size = width
        self.conv = nn.Sequential(*layers)
        self.keypoints = nn.Conv2d(size, KEYPOINTS, 1)
        self.soft_argmax = SpatialSoftArgmax(image_hw[0] // 4, image_hw[1] // 4)
        self.width = 2 * KEYPOINTS + size

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        maps = self.conv(image - 0.5)
        return torch.cat([self.soft_argmax(self.keypoints(maps)), maps.mean((2, 3))], 1)


class VisualChunkPolicy(nn.Module):
    """``(image, state)`` -> the temporally ensembled action of this step, per env."""

    def __init__(
        self, image_hw: tuple[int, int], state_mean, state_std, act_mean, act_std, act_low,
        act_high, chunk: int, hidden: list[int], decay: float, frame, obs_keys: list[str],
    ):  # fmt: skip
        super().__init__()
        act_dim = len(act_low)
        self.chunk, self.act_dim = chunk, act_dim
        self.camera = CAMERA
        self.obs_keys = list(obs_keys)
        self.image_hw = [int(image_hw[0]), int(image_hw[1])]
        coef, joint = frame
        for name, value in dict(
            state_mean=state_mean, state_std=state_std, act_mean=act_mean, act_std=act_std,
            act_low=act_low, act_high=act_high, coef=coef,
        ).items():  # fmt: skip
            self.register_buffer(name, torch.as_tensor(np.asarray(value), dtype=torch.float32))
        self.register_buffer("joint", torch.as_tensor(np.asarray(joint), dtype=torch.long))
        self.encoder = Encoder(image_hw)
        size = CHANNELS[-1]
        mlp: list[nn.Module] = []
        width_in = 2 * KEYPOINTS + size + len(state_mean)
        for width in hidden:
            mlp += [nn.Linear(width_in, width), nn.ReLU()]
            width_in = width
        mlp.append(nn.Linear(width_in, chunk * act_dim))
        self.head = nn.Sequential(*mlp)
        features = 2 * KEYPOINTS + size
        self.aux = nn.Sequential(
            nn.Linear(features, AUX_HIDDEN), nn.ReLU(), nn.Linear(AUX_HIDDEN, AUX_DIM)
        )
        self.ensemble = TemporalEnsemble(chunk, act_dim, decay)

    def raw_normalised(self, image: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Float images ``(B, 3, H, W)`` and normalised states -> normalised chunks."""
        return self.heads(image, state)[0]

    def heads(self, image: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The normalised chunks and the auxiliary head's normalised targets (training)."""
        features = self.encoder(image)
        chunks = self.head(torch.cat([features, state], 1)).view(-1, self.chunk, self.act_dim)
        return chunks, self.aux(features)

    def anchor(self, state: torch.Tensor) -> torch.Tensor:
        return state[:, self.joint] * self.coef

    @torch.jit.export
    def reset(self) -> None:
        self.ensemble.reset()

    def forward(self, image: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        x = image.permute(0, 3, 1, 2).float() / 255.0
        normalised = (state - self.state_mean) / self.state_std
        chunk = self.raw_normalised(x, normalised) * self.act_std + self.act_mean
        anchor = self.anchor(state)
        action = self.ensemble(chunk + anchor[:, None], anchor)
        return torch.clamp(action, self.act_low, self.act_high)


def augment(
    images: torch.Tensor, generator: torch.Generator, shift: int = SHIFT_PX
) -> torch.Tensor:
    """``(B, 3, H, W)`` float images, each shifted by up to ``shift`` pixels (edges
    replicated) and colour-jittered."""
    b, _, h, w = images.shape
    padded = F.pad(images, (shift,) * 4, mode="replicate")
    dx = torch.randint(0, 2 * shift + 1, (b,), generator=generator)
    dy = torch.randint(0, 2 * shift + 1, (b,), generator=generator)
    rows = (dy[:, None] + torch.arange(h)[None])[:, None, :, None].expand(b, 3, h, w + 2 * shift)
    shifted = padded.gather(2, rows)
    cols = (dx[:, None] + torch.arange(w)[None])[:, None, None, :].expand(b, 3, h, w)
    shifted = shifted.gather(3, cols)

    def uniform(size, spread):
        return 1.0 + spread * (2 * torch.rand(size, generator=generator) - 1)

    mean = shifted.mean((1, 2, 3), keepdim=True)
    out = (shifted - mean) * uniform((b, 1, 1, 1), CONTRAST) + mean
    out = out * uniform((b, 1, 1, 1), BRIGHTNESS) * uniform((b, 3, 1, 1), GAIN)
    return out.clamp(0.0, 1.0)


def contact_sheet(path: Path, out: Path, episodes: int = 8, scale: int = 2) -> Path:
    """A PNG of what the policy sees: per column an episode of the dataset (rooms differ when
    it was collected with ``--rooms``), its first frame above and its middle frame below, each
    enlarged ``scale`` times."""
    import imageio.v2 as imageio

    from embodied_envs.paths import atomic_output

    columns = []
    with h5py.File(path, "r") as f:
        names = sorted((k for k in f if k.startswith("traj_")), key=lambda k: int(k[5:]))
        for name in names[:episodes]:
            rgb = f[f"{name}/obs/sensor_data/{CAMERA}/rgb"]
            columns.append(np.concatenate([rgb[0], rgb[len(rgb) // 2]], 0))
    sheet = np.concatenate(columns, 1).repeat(scale, 0).repeat(scale, 1)
    with atomic_output(out) as tmp:
        imageio.imwrite(tmp, sheet)
    return out


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="a contact sheet of an rgb dataset's frames")
    ap.add_argument("--demos", type=Path, required=True, help="an rgb dataset (.h5)")
    ap.add_argument("--out", type=Path, required=True, help="the PNG to write")
    ap.add_argument("--episodes", type=int, default=8)
    cli = ap.parse_args()
    print(f"wrote {contact_sheet(cli.demos, cli.out, cli.episodes)}")
