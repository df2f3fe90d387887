"""Room pools: the splat backgrounds an env draws each episode's room from.

A room is a folder holding a 3DGS ``gs_model.ply`` in the frame of the shipped room (Y-up,
metres, the floor at y = 0, its centre under the layout's background pose), as EmbodiedGen's
background assets are. The env keyword ``rooms`` (and ``--rooms`` of ``collect`` and ``eval``)
names a pool: ``"shipped"`` (:func:`shipped_rooms`), a room folder, a folder of room folders, a
glob, or a list of these. Each episode draws one room of the pool from its seed
(:func:`draw_rooms`); the layout's objects, table and robot are unchanged.
"""

from __future__ import annotations

import glob
import os
from pathlib import Path

import numpy as np

from embodied_envs.paths import data_root

SHIPPED = "shipped"  # the pool of rooms shipped with the package
ROOM_FILE = "gs_model.ply"  # the splat a room folder holds
PLY_MAGIC = b"ply"  # the first bytes of a PLY file


class RoomError(ValueError):
    """A room pool that names no room, or a room that cannot be read (names the value, the
    file and the fix)."""


def shipped_rooms() -> list[Path]:
    """The shipped pool: the shipped layouts' own room (``assets/background``) and the rooms
    of ``data/rooms/`` (made by ``tools/make/make_rooms.py``), in that order."""
    rooms = [data_root() / "assets" / "background"]
    rooms += sorted(p for p in (data_root() / "rooms").iterdir() if (p / ROOM_FILE).is_file())
    return rooms


def _rooms_of(entry: str | os.PathLike) -> list[Path]:
    """The room folders one entry of a pool names (absolute), possibly none."""
    text = str(entry)
    if text == SHIPPED:
        return shipped_rooms()
    paths = [Path(p) for p in sorted(glob.glob(text))] if glob.has_magic(text) else [Path(text)]
    rooms = []
    for path in paths:
        if path.is_file() and path.name == ROOM_FILE:
            rooms.append(path.parent)
        elif (path / ROOM_FILE).is_file():
            rooms.append(path)
        elif path.is_dir():  # a folder of room folders
            rooms += sorted(p for p in path.iterdir() if (p / ROOM_FILE).is_file())
    return [r.resolve() for r in rooms]


def resolve_rooms(value: str | os.PathLike | list | tuple | None) -> list[Path] | None:
    """The room folders of a pool, in order, each once; ``None`` for ``None`` (every layout in
    its own room).

    Raises:
        RoomError: an entry that names no room folder (one with a ``gs_model.ply``), or a
            room's ``gs_model.ply`` that is not a PLY file.
    """
    if value is None:
        return None
    entries = [value] if isinstance(value, (str, os.PathLike)) else list(value)
    if not entries:
        raise RoomError(f"rooms={value!r} names no room. Fix: {SHIPPED!r}, a folder or a glob")
    rooms: list[Path] = []
    for entry in entries:
        if not isinstance(entry, (str, os.PathLike)):
            raise RoomError(f"rooms: {entry!r} is not a path. Fix: {SHIPPED!r}, a folder or a glob")
        found = _rooms_of(entry)
        if not found:
            raise RoomError(
                f"rooms: {entry} holds no room (a folder with a {ROOM_FILE}). Fix: name room "
                f"folders, a folder of them, a glob, or {SHIPPED!r}; make a room's splat with "
                "`embodied-envs splat from-mesh ROOM_MESH --out FOLDER/gs_model.ply`"
            )
        rooms += [r for r in found if r not in rooms]
    for room in rooms:
        with open(room / ROOM_FILE, "rb") as f:
            head = f.read(len(PLY_MAGIC))
        if head != PLY_MAGIC:
            raise RoomError(
                f"{room / ROOM_FILE}: not a PLY file (it starts with {head!r}). Fix: a 3DGS "
                "gs_model.ply, e.g. from `embodied-envs splat from-mesh`"
            )
    return rooms


def draw_rooms(rng, count: int) -> np.ndarray:
    """Each env's room index in a pool of ``count`` rooms, drawn from its episode RNG (a
    ManiSkill ``BatchedRNG`` over the envs being reset): uniform, one draw per env."""
    return np.asarray(rng.randint(count), dtype=np.int64).reshape(-1)
