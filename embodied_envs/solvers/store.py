"""The expert's per-asset results kept between runs, in the cache folder.

Grasp synthesis (``grasps.py``) takes 0.3-3 s of CPU per asset, once per process: every
``collect``, ``demo`` or ``eval`` paid it again for the same meshes (a fifth of the
per-process overhead of a 20-demonstration ``collect`` of the default layout). :func:`cached`
keeps such a result in ``expert/`` of the cache folder (``layout/collision.py``:
``$EMBODIED_ENVS_CACHE``, else ``~/.cache/embodied_envs``; never beside the user's files), one
``.npz`` per result, named by a digest of everything that determines it: the bytes of the files
it is computed from, its settings, the source of the modules that compute it and the versions
of numpy and trimesh. The same inputs find the same file, whose arrays are the computed ones bit
for bit (``.npz`` is lossless); anything changed gives another name. A file that cannot be read
is computed again and rewritten; a folder that cannot be written costs only the time.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.metadata
import sys
import zipfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

import numpy as np

from embodied_envs.layout.collision import cache_folder
from embodied_envs.paths import atomic_output

T = TypeVar("T")
LIBRARIES = ("numpy", "trimesh")  # whose versions name a result too (sampling, float kernels)


def store_folder() -> Path:
    """Where results are kept: ``expert/`` in the cache folder."""
    return cache_folder().parent / "expert"


@functools.cache
def code_version(modules: tuple[str, ...]) -> bytes:
    """A digest of the source files of ``modules`` (imported names) and of the versions of
    :data:`LIBRARIES`: an edit of any of them names results anew."""
    digest = hashlib.sha256()
    for name in modules:
        digest.update(Path(sys.modules[name].__file__).read_bytes())
    for name in LIBRARIES:
        digest.update(f"{name} {importlib.metadata.version(name)}".encode())
    return digest.digest()


def result_name(kind: str, files: Iterable[Path | None], settings: object, modules) -> str:
    """The name of a result of ``kind`` computed from ``files`` (their bytes; None: no file)
    with ``settings`` (its ``repr``: frozen dataclasses and tuples of numbers) by ``modules``."""
    digest = hashlib.sha256(kind.encode())
    for path in files:  # each file's length first: no two lists of files read alike
        data = b"" if path is None else Path(path).read_bytes()
        digest.update(b"-" if path is None else len(data).to_bytes(8, "little") + data)
    digest.update(repr(settings).encode())
    digest.update(code_version(tuple(modules)))
    return f"{kind}-{digest.hexdigest()[:32]}"


def cached(name: str, compute: Callable[[], T], kind: type[T]) -> T:
    """The result stored under ``name`` (:func:`result_name`), else ``compute()`` stored there.

    ``kind`` is its class: ``np.ndarray``, or a dataclass whose fields hold arrays, tuples of
    arrays or None."""
    path = store_folder() / f"{name}.npz"
    try:
        with np.load(path) as data:
            return _unpack(kind, dict(data))
    except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile):
        pass  # absent, empty, cut short or of another layout: computed again
    value = compute()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as tmp:
            with open(tmp, "wb") as fh:  # a file object: numpy adds no second suffix
                np.savez(fh, **_pack(value))
    except OSError:  # a read-only cache folder: computed again next time
        pass
    return value


def _pack(value) -> dict[str, np.ndarray]:
    if isinstance(value, np.ndarray):
        return {"value": value}
    out = {}
    for f in dataclasses.fields(value):
        item = getattr(value, f.name)
        if isinstance(item, tuple):
            out[f"{f.name}#"] = np.array(len(item))
            out.update({f"{f.name}.{i}": np.asarray(x) for i, x in enumerate(item)})
        elif item is not None:
            out[f.name] = np.asarray(item)
    return out


def _unpack(kind: type[T], data: dict[str, np.ndarray]) -> T:
    if kind is np.ndarray:
        return data["value"]
    values = {}
    for f in dataclasses.fields(kind):
        if f"{f.name}#" in data:
            values[f.name] = tuple(data[f"{f.name}.{i}"] for i in range(int(data[f"{f.name}#"])))
        elif f.name in data:
            values[f.name] = data[f.name]
        elif f.default is dataclasses.MISSING:
            raise KeyError(f.name)  # a file of another layout: computed again
    return kind(**values)
