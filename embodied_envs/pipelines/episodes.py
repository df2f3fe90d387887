"""The one episode loop of ``demo``, ``collect`` and ``eval``.

:func:`run_episode` resets the env with a seed (over a layout set the seed draws the episode's
layout: a reconfiguration), lets a driver step it through a :class:`Tally` (the scripted expert,
:func:`expert`, or a policy loop), and grades the end with ``evaluate()["success"]``, into one
:class:`Episode`. The tally counts the steps, the return and ``fail``, and keeps every k-th
frame; :func:`write_video` writes frames as an MP4 (under a temporary name, then renamed). Each
pipeline writes its own files from the episodes.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from embodied_envs.layout import load_layout
from embodied_envs.layout.sets import layout_files
from embodied_envs.paths import atomic_output

# steps an episode through the tally: (tally, first observation, seed) -> the expert's failed
# plans ("stage: why"; [] for a policy)
Driver = Callable[["Tally", object, int], list]


@dataclass
class Episode:
    """One episode as it ran (the record of every pipeline).

    Attributes:
        layout: the layout file it ran in (over a set: the one its seed drew).
        seed: its reset seed.
        success: ``evaluate()["success"]`` at its end.
        fail: ``info["fail"]`` at some step (an object fell off the table).
        steps: control steps taken.
        episode_return: the sum of the env's rewards (rounded to 6 decimals).
        instruction: its task in words.
        plan_failures: the expert's failed plans (``"stage: why"``); empty for a policy.
        unmet: on failure, the conditions of success its end missed, per mover
            (``"can: not released, not at rest"``, ``env.task_reader.unmet()``).
        wall_time_s: seconds from the reset to its end.
        kept: ``collect``: whether it went into the dataset.
        video: ``eval``: its video's file name, if one was kept.
        frames: the frames kept (``film_every``), ``(H, W, 3)`` uint8.
    """

    layout: str
    seed: int
    success: bool
    fail: bool
    steps: int
    episode_return: float
    instruction: str = ""
    plan_failures: list[str] = field(default_factory=list)
    unmet: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0
    kept: bool = True
    video: str | None = None
    frames: list = field(default_factory=list, repr=False)

    @property
    def failure(self) -> str | None:
        """The stage that failed first (``"execution"`` when every plan ran) and the conditions
        of success its end missed: ``"execution (can: not resting on its floor)"``; None on
        success."""
        if self.success:
            return None
        stage = self.plan_failures[0].split(":")[0] if self.plan_failures else "execution"
        return f"{stage} ({'; '.join(self.unmet)})" if self.unmet else stage


def frame(env) -> np.ndarray:
    """The first env's rendered image, ``(H, W, 3)`` uint8."""
    img = env.render()
    img = img.cpu().numpy() if hasattr(img, "cpu") else np.asarray(img)
    return img[0] if img.ndim == 4 else img


def film_mode(layout) -> str:
    """The render mode that films a layout (or every layout of a set): ``hybrid`` when each
    background has a splat, the simulator's ``rgb_array`` otherwise."""
    files = layout_files(layout)
    splats = all(load_layout(f, check_poses=False).gs_model_path().is_file() for f in files)
    return "hybrid" if splats else "rgb_array"


class Tally:
    """A pass-through of ``env``'s interface (the expert's solver steps through it too) that
    counts an episode's steps, return and fail, and keeps the frame after every
    ``film_every``-th step (0: none)."""

    def __init__(self, env, film_every: int = 0):
        self.env, self.film_every = env, film_every
        self.steps, self.ret, self.fail = 0, 0.0, False
        self.frames: list[np.ndarray] = []

    def __getattr__(self, name):
        return getattr(self.env, name)

    def film(self) -> None:
        """Keep the frame now (when filming)."""
        if self.film_every:
            self.frames.append(frame(self.env))

    def step(self, action):
        import torch  # in the process that runs episodes; `embodied-envs --help` stays without it

        out = self.env.step(action)
        self.steps += 1
        self.ret += float(_first(out[1], torch))
        self.fail |= bool(_first(out[4]["fail"], torch))
        if self.film_every and self.steps % self.film_every == 0:
            self.film()
        return out


def _first(value, torch):
    """The first env's number of ``value`` (a tensor, an array or a number; ``torch``: the
    module, imported where episodes run), as Python's ``float``/``bool`` take it."""
    if isinstance(value, torch.Tensor) and value.numel() == 1:
        return value.item()  # the one env's: the usual case, without a reshaped view
    return torch.as_tensor(value).reshape(-1)[0].item()


def expert(tally: Tally, obs, seed: int, config=None) -> list[str]:
    """The driver of the scripted expert: it plans and steps the episode itself (``config``: a
    ``SolverConfig``, None for the default one)."""
    # the solver (torch, SAPIEN, mplib) only where the expert runs, not for --help
    from embodied_envs.solvers.pick_place import PickPlaceSolver

    return PickPlaceSolver(tally, config, seed=seed).solve().reports[0].plan_failures


def run_episode(
    env, seed: int, drive: Driver = expert, film_every: int = 0, closing_frame: bool = False
) -> Episode:
    """One seeded episode of ``env`` (one env; any wrapper: ``RecordEpisode`` records it).

    Args:
        env: the env.
        seed: the reset seed.
        drive: steps the env through the tally (:func:`expert`, or a policy loop).
        film_every: keep the frame after the reset and after every k-th step (0: none).
        closing_frame: when filming, keep the frame at the end too.
    """
    t0 = time.perf_counter()
    u = env.unwrapped
    # over a set, the seed draws the episode's layout: a reconfiguration
    options = dict(reconfigure=True) if u.layout_set.varies else None
    obs, _ = env.reset(seed=seed, options=options)
    layout = str(u.layouts[0].source)
    tally = Tally(env, film_every)
    tally.film()
    failures = drive(tally, obs, seed)
    if closing_frame:
        tally.film()
    success = bool(u.evaluate()["success"][0])
    return Episode(
        layout=layout,
        seed=seed,
        success=success,
        fail=tally.fail,
        steps=tally.steps,
        episode_return=round(tally.ret, 6),
        instruction=u.instructions[0],
        plan_failures=list(failures),
        unmet=[] if success else u.task_reader.unmet()[0],
        wall_time_s=time.perf_counter() - t0,
        frames=tally.frames,
    )


def write_video(
    path: Path, frames: Iterable[np.ndarray], fps: int, quality: float | None = None
) -> int:
    """``frames`` as an H.264 MP4 at ``path``, written under a temporary name and renamed;
    returns the number of frames. ``quality``: imageio's variable bit rate, 0-10 (None:
    ffmpeg's own rate control, as imageio's writer given no quality)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    with atomic_output(path) as tmp:
        w = imageio.get_writer(tmp, fps=fps, codec="libx264", quality=quality, macro_block_size=1)
        try:
            for f in frames:
                w.append_data(f)
                n += 1
        finally:  # ffmpeg has quit before the temporary file is renamed or removed (imageio's
            w.close()  # `with` closes it on success only, leaving a stray file on an error)
    return n
