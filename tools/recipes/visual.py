"""What the visual recipe (``perceive.py``) shares: the camera it reads, the image encoder and
the frames' augmentation, and a contact sheet of a dataset's frames (``python visual.py``).

The encoder is a small convolutional net over the ``base_camera``'s RGB frame ending in a
spatial soft-argmax (each of ``KEYPOINTS`` feature maps gives its expected image position, as
robomimic's and diffusion policy's image encoders do) and the last maps' means. Training
augments each frame with a background swap (the frame's own room replaced by another, where the
frame's pixels are not its background's: ``foreground_masks``, ``swap_backgrounds``), a random
shift (DrQ's augmentation) and colour jitter (brightness, contrast, per-channel gain); rooms
differ between episodes too when the dataset was collected with ``--rooms``.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

CAMERA = "base_camera"  # the env's sensor camera
KEYPOINTS = 32  # spatial soft-argmax keypoints
CHANNELS = (16, 32, 32)  # the conv layers' widths (wider: 4x the training time on 2 cores)
SHIFT_PX = 4  # random shift augmentation, pixels each way
BRIGHTNESS, CONTRAST, GAIN = 0.2, 0.2, 0.1  # colour jitter: relative ranges


def is_visual(path: Path) -> bool:
    """Whether the dataset's observations hold camera frames (``sensor_data/.../rgb``)."""
    with h5py.File(path, "r") as f:
        names = [k for k in f.keys() if k.startswith("traj_")]
        if not names:
            return False
        obs = f[names[0]].get("obs")
        return isinstance(obs, h5py.Group) and f"sensor_data/{CAMERA}/rgb" in obs


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


def foreground_masks(frames: torch.Tensor, backgrounds: torch.Tensor, least: float,
                     batch: int = 1024) -> torch.Tensor:  # fmt: skip
    """``(N, H, W, 3)`` uint8 hybrid frames and the ``(K, H, W, 3)`` backgrounds they may be
    composited over -> ``(N, H, W)`` bool: the pixels that are not their background's. A frame's
    background is the one it shares the most pixels with (the composite copies its pixels
    exactly); a frame that shares under ``least`` of its pixels with every one (another camera)
    is all foreground, kept whole."""
    out = torch.ones(frames.shape[:3], dtype=torch.bool)
    for i in range(0, len(frames), batch):
        same = (frames[i : i + batch, None] == backgrounds[None]).all(-1)  # (n, K, H, W)
        share = same.float().mean((2, 3))
        best = share.argmax(1)
        mine = same[torch.arange(len(same)), best]
        out[i : i + batch] = ~mine | (share.amax(1) < least)[:, None, None]
    return out


def swap_backgrounds(images: torch.Tensor, masks: torch.Tensor, rooms: torch.Tensor,
                     generator: torch.Generator, share: float) -> torch.Tensor:  # fmt: skip
    """``(B, 3, H, W)`` float images, a ``share`` of them (drawn) with their background pixels
    (``masks`` ``(B, H, W)`` False) replaced by those of a room drawn from ``rooms``
    ``(R, 3, H, W)``: the robot, the table and the objects over a room no frame showed."""
    b = images.shape[0]
    chosen = torch.rand(b, generator=generator) < share
    room = rooms[torch.randint(len(rooms), (b,), generator=generator)]
    keep = masks[:, None] | ~chosen[:, None, None, None]
    return torch.where(keep, images, room)


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
