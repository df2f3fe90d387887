"""Many scenes behind one ``layout_file``: layout sets and asset pools.

- A **layout set** is what ``layout_file`` names: one file, a folder (its ``*.json`` files,
  sorted by name), a glob (``"layouts/*.json"``), or a list of any of these, in order.
- An **asset pool** is an ``assets`` entry of a layout that names a folder of asset folders
  instead of one asset folder (it holds no URDF of its own, and its sub-folders each hold
  ``<node>.urdf`` or ``<sub-folder>.urdf``): add an asset folder to it and it joins the pool.

Each env draws one layout of the set and one member of each pool per configuration
(:meth:`LayoutSet.draw`), from the env's configuration seed: the same seed draws the same scene.
A set of one layout without pools draws nothing, so its placements are those of a plain layout.
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.folders import resolve_path
from embodied_envs.layout.loader import load_layout
from embodied_envs.layout.pools import asset_pools, with_assets, with_first_members
from embodied_envs.layout.schema import LayoutInfo

MAX_SET_SIZE = 10_000  # layouts in one set: more is a mistyped glob, not a task
DRAW_STREAM = 1  # the configuration seed's stream for scene draws (placement uses another)
GLOB_CHARS = "*?["

LayoutSpec = str | os.PathLike | list | tuple  # what ``layout_file`` accepts (plus None)


def spec_name(spec: str | os.PathLike) -> str:
    """A name for one ``layout_file`` value: a file's stem, a folder's name, or the name of the
    folder a glob starts in."""
    text = os.fspath(spec)
    path = Path(text).expanduser()
    if path.is_dir():
        return path.resolve().name
    if any(c in text for c in GLOB_CHARS) and not path.exists():
        fixed = text[: min(text.index(c) for c in GLOB_CHARS if c in text)]
        folder = Path(fixed) if fixed.endswith(("/", os.sep)) or not fixed else Path(fixed).parent
        return folder.expanduser().resolve().name
    return path.stem


def layout_files(spec: LayoutSpec) -> list[Path]:
    """The layout files a ``layout_file`` value names, absolute, in order, each once.

    Raises:
        LayoutError: a value that is not a path, a folder without ``*.json`` files, a glob that
            matches none, an empty list, a path that does not exist, or a set over
            ``MAX_SET_SIZE``.
    """
    items = list(spec) if isinstance(spec, list | tuple) else [spec]
    if not items:
        raise LayoutError(
            "layout_file=[]: an empty list names no layout. Fix: give one or more layout "
            "files, a folder of them, or a glob."
        )
    files: list[Path] = []
    for item in items:
        if not isinstance(item, str | os.PathLike) or isinstance(item, bytes):
            raise LayoutError(
                f"layout_file: {item!r} is not a path. Fix: give layout files, folders or globs"
                " as strings."
            )
        text = os.fspath(item)
        path = Path(text).expanduser()
        if path.is_dir():
            found = sorted(path.glob("*.json"))
            if not found:
                raise LayoutError(
                    f"{path}: the folder holds no *.json layout file. Fix: put layout files in "
                    "it, or name the files themselves."
                )
        elif any(c in text for c in GLOB_CHARS) and not path.exists():
            found = sorted(Path(p) for p in glob.glob(str(path), recursive=True))
            found = [p for p in found if p.is_file()]
            if not found:
                raise LayoutError(
                    f"{text}: the glob matches no layout file. Fix: check the pattern (it is "
                    f"matched from the working directory, {os.getcwd()})."
                )
        else:
            found = [path]  # a missing file is named by load_layout
        files += [resolve_path(p, "layout_file") for p in found]
    unique = list(dict.fromkeys(files))
    if len(unique) > MAX_SET_SIZE:
        raise LayoutError(
            f"layout_file names {len(unique):,} layout files, over the {MAX_SET_SIZE:,} a set may"
            " hold. Fix: narrow the folder or glob."
        )
    return unique


@dataclass(frozen=True)
class LayoutSet:
    """The layouts a ``layout_file`` names, loaded and checked, with their asset pools.

    Attributes:
        layouts: the set's layouts, in order.
        pools: per layout, each pooled node's members (``assets`` entries).
    """

    layouts: tuple[LayoutInfo, ...]
    pools: tuple[dict[str, list[str]], ...]

    @classmethod
    def load(cls, spec: LayoutSpec, check_poses: bool = True) -> LayoutSet:
        """Load and check every layout of a set and every member of its pools.

        Raises:
            LayoutError: naming the layout file, the node and the bad pool member.
        """
        layouts, pools = [], []
        for path in layout_files(spec):
            info = load_layout(path, check_poses=check_poses)  # pools: every member checked
            layouts.append(info)
            pools.append(asset_pools(info))
        return cls(tuple(layouts), tuple(pools))

    def __len__(self) -> int:
        return len(self.layouts)

    @property
    def files(self) -> list[Path]:
        return [x.source for x in self.layouts]

    @property
    def varies(self) -> bool:
        """Whether configurations draw anything (several layouts or a pool)."""
        return len(self.layouts) > 1 or any(self.pools)

    def members(self) -> list[LayoutInfo]:
        """Every layout of the set with every single pool member in place (for checks that
        each asset can be placed)."""
        out = []
        for layout, pooled in zip(self.layouts, self.pools, strict=True):
            out.append(with_first_members(layout))
            out += [with_assets(layout, {n: m}) for n, ms in pooled.items() for m in ms[1:]]
        return out

    def draw(self, seed: int, env: int) -> LayoutInfo:
        """The scene of env ``env`` for a configuration seed: one layout of the set, one
        member of each of its pools (nothing is drawn when nothing varies)."""
        if not self.varies:
            return self.layouts[0]
        seq = np.random.SeedSequence([int(seed) % 2**63, int(env), DRAW_STREAM])
        rng = np.random.default_rng(seq)
        i = int(rng.integers(len(self.layouts)))
        choices = {n: ms[int(rng.integers(len(ms)))] for n, ms in self.pools[i].items()}
        return with_assets(self.layouts[i], choices)
