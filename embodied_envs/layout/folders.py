"""Asset folders as the file system holds them: every entry reachable and readable.

A symbolic link loop or an unreadable file in an asset folder would otherwise fail deep inside
the XML reader, trimesh or SAPIEN (Python's ``Path.resolve`` raises a bare ``RuntimeError`` on a
loop), naming neither the node nor the fix; the loader walks each asset folder first.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from embodied_envs.layout.errors import LayoutError

MAX_FOLDER_ENTRIES = 10_000  # an asset folder holds one asset's URDF, meshes and textures
LOOP_FIX = "Fix: point the link at a real file or folder, or remove it."


def resolve_path(path: str | os.PathLike, where: str) -> Path:
    """``path`` absolute, every symbolic link followed.

    Args:
        path: the path to resolve.
        where: whose path it is, for the message (a file, a field).

    Raises:
        LayoutError: the path runs into a symbolic link loop.
    """
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError) as e:  # Python 3.11: RuntimeError("Symlink loop from ...")
        raise LayoutError(f"{where}: {path} is a symbolic link loop ({e}). {LOOP_FIX}") from None


def check_folder(folder: str | os.PathLike, recursive: bool = True) -> None:
    """Every entry of ``folder`` (and, with ``recursive``, of its sub-folders) can be reached and
    read: no symbolic link loop (a link to itself, or a folder link back to a folder holding
    it), no file that cannot be opened, no sub-folder that cannot be listed. Linked folders are
    not entered (the files an asset uses lie in its folder, where the walk meets them); dangling
    links and special files are left to the checks of the files a URDF names.

    Raises:
        LayoutError: naming the first bad path and the fix.
    """
    stack, count = [os.fspath(folder)], 0
    while stack:
        current = stack.pop()
        try:
            with os.scandir(current) as it:
                entries = sorted(it, key=lambda e: e.name)
        except OSError as e:
            raise LayoutError(
                f"{current}: the folder cannot be listed ({e.strerror or e}). Fix: make it"
                " readable (chmod a+rx)."
            ) from None
        for entry in entries:
            count += 1
            if count > MAX_FOLDER_ENTRIES:
                raise LayoutError(
                    f"{folder}: over {MAX_FOLDER_ENTRIES:,} entries, more than an asset folder"
                    " holds (one asset's URDF, meshes and textures). Fix: point the layout's"
                    " assets entry at the asset's own folder."
                )
            try:
                st = os.stat(entry.path)  # follows links
            except OSError as e:
                if e.errno == errno.ELOOP:
                    raise LayoutError(
                        f"{entry.path}: a symbolic link loop ({e.strerror}). {LOOP_FIX}"
                    ) from None
                continue  # a dangling link: named where a URDF uses it
            if stat.S_ISDIR(st.st_mode) and entry.is_symlink():
                target = os.path.realpath(entry.path)
                if Path(os.path.realpath(current)).is_relative_to(target):
                    raise LayoutError(
                        f"{entry.path}: a symbolic link loop (it links to {target}, a folder"
                        f" holding it). {LOOP_FIX}"
                    )
            elif stat.S_ISDIR(st.st_mode) and recursive:
                stack.append(entry.path)
            elif stat.S_ISREG(st.st_mode):
                try:
                    with open(entry.path, "rb"):
                        pass
                except OSError as e:
                    raise LayoutError(
                        f"{entry.path}: the file cannot be read ({e.strerror or e}). Fix: make it"
                        " readable (chmod a+r), or remove it if the asset does not use it."
                    ) from None
