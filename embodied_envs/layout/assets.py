"""EmbodiedGen asset folders: URDF parsing and the Z-up geometry that placement needs.

An asset folder holds ``<stem>.urdf`` (one link with a visual and a collision mesh), the visual
mesh and ``mesh/<stem>_collision.obj`` whose connected components are convex parts. Meshes are
stored Y-up and reach Z-up through the URDF ``<origin rpy="1.5708 0 0">``.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from embodied_envs.layout.collision import (
    MIN_COLLISION_THICKNESS,
    convex_collision,
    load_mesh,
    obj_objects,
    thickness,
)
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.folders import resolve_path
from embodied_envs.layout.pose import rpy_to_matrix, rpy_to_quat_wxyz

STATIC_FRICTION_RANGE = (0.1, 0.7)  # mu1 is clipped to this range
DYNAMIC_FRICTION_RANGE = (0.1, 0.6)  # mu2 is clipped to this range
DEFAULT_STATIC_FRICTION = 0.5  # when the URDF has no mu1
DEFAULT_DYNAMIC_FRICTION = 0.4  # when the URDF has no mu2
RESTITUTION = 0.05
DEFAULT_DENSITY = 1000.0  # kg/m^3, when the URDF gives no mass
MASS_RANGE = (1e-3, 1e3)  # kg: a graspable or supporting object (a paper clip to a table)
HEAVY_COLLISION_FACES = 50_000  # a collision mesh with more faces is warned about (cost)
MAX_IMAGE_SIDE = 8192  # pixels a side of any image rendered or read: larger ones are refused
MAX_OBJECT_SIZE = 10.0  # m: a collision mesh larger than this across is refused (a mesh in
# millimetres reads 1000x too large: a 10 cm can is 100 m)
# the first bytes of files that are not meshes, and what they are (a mesh named as the URDF
# says but holding other bytes is named as what it holds, not as an empty mesh)
NOT_MESH_SIGNATURES = {
    b"\x89PNG\r\n\x1a\n": "a PNG image",
    b"\xff\xd8\xff": "a JPEG image",
    b"GIF8": "a GIF image",
    b"PK\x03\x04": "a zip archive",
    b"%PDF": "a PDF document",
    b"\x1f\x8b": "gzip-compressed data",
}


def node_stem(node: str) -> str:
    """File stem of a layout node: spaces become underscores."""
    return node.replace(" ", "_")


@dataclass(frozen=True)
class MeshRef:
    """A mesh of the link with its ``<origin>`` and ``scale``."""

    path: Path
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    source: Path | None = None  # the file the URDF names, when ``path`` is made from it (its
    # convex parts, in the cache folder: layout/collision.py): what messages name

    @property
    def named(self) -> Path:
        """The file the user wrote: what a message about this mesh names."""
        return self.path if self.source is None else self.source

    def to_link_frame(self, vertices: np.ndarray) -> np.ndarray:
        """Map mesh vertices into the link (actor) frame: scale, rotate, translate."""
        v = np.asarray(vertices, dtype=np.float64) * np.asarray(self.scale)
        return v @ rpy_to_matrix(self.rpy).T + np.asarray(self.xyz)

    def sapien_pose(self):
        import sapien  # only for the simulator: layout commands start without SAPIEN

        return sapien.Pose(p=list(self.xyz), q=list(rpy_to_quat_wxyz(self.rpy)))


@dataclass(frozen=True)
class AssetSpec:
    """Everything needed to build one EmbodiedGen asset."""

    name: str
    urdf_path: Path
    visual: MeshRef
    collision: MeshRef
    static_friction: float
    dynamic_friction: float
    mass: float | None

    @property
    def restitution(self) -> float:
        return RESTITUTION


def urdf_path_for(asset_dir: Path, node: str) -> Path:
    """An asset folder's URDF: ``<node stem>.urdf``, else ``<folder name>.urdf`` (the name a
    member of an asset pool has, EmbodiedGen's ``<asset>/<asset>.urdf``); the first name when
    neither exists."""
    asset_dir = Path(asset_dir)
    named = asset_dir / f"{node_stem(node)}.urdf"
    own = asset_dir / f"{asset_dir.name}.urdf"
    return own if not named.is_file() and own.is_file() else named


def _origin(elem: ET.Element | None, urdf: Path, where: str):
    if elem is None:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    try:
        xyz = tuple(float(v) for v in elem.get("xyz", "0 0 0").split())
        rpy = tuple(float(v) for v in elem.get("rpy", "0 0 0").split())
    except ValueError as e:
        raise LayoutError(f"{urdf}: {where}/origin has a non-numeric xyz or rpy ({e})") from e
    if len(xyz) != 3 or len(rpy) != 3 or not all(map(math.isfinite, xyz + rpy)):
        raise LayoutError(f"{urdf}: {where}/origin needs 3 finite numbers in xyz and in rpy")
    return xyz, rpy


def _mesh(link: ET.Element, tag: str, urdf: Path) -> MeshRef:
    elems = link.findall(tag)
    if len(elems) > 1:
        raise LayoutError(
            f"{urdf}: the link has {len(elems)} <{tag}> elements; an asset is built from one"
            f" (EmbodiedGen writes one). Fix: merge their meshes into one {tag} mesh file."
        )
    elem = elems[0] if elems else None
    if elem is None:
        raise LayoutError(
            f"{urdf}: link has no <{tag}>. Fix: add a <{tag}><geometry><mesh filename=...>"
            f" element (EmbodiedGen assets have both <visual> and <collision>)."
        )
    mesh = elem.find("geometry/mesh")
    if mesh is None or not mesh.get("filename"):
        raise LayoutError(f"{urdf}: <{tag}> has no <geometry><mesh filename=...>. Fix: add it.")
    filename = mesh.get("filename").replace("package://", "")
    path = resolve_path(urdf.parent / filename, f"{urdf}: <{tag}> mesh file")
    if not path.is_relative_to(urdf.parent):
        raise LayoutError(
            f"{urdf}: <{tag}> mesh file {filename} lies outside the asset folder {urdf.parent}"
            " (an asset folder must be whole to be moved or copied). Fix: copy the mesh into"
            " the asset folder and name it relative to the URDF."
        )
    if not path.is_file():
        raise LayoutError(
            f"{urdf}: <{tag}> mesh file {filename} does not exist (looked at {path})."
            " Fix: correct the filename or restore the file."
        )
    try:
        scale = tuple(float(v) for v in mesh.get("scale", "1 1 1").split())
    except ValueError as e:
        raise LayoutError(f"{urdf}: <{tag}> mesh scale is not numeric ({e})") from e
    if len(scale) == 1:
        scale = scale * 3
    if len(scale) != 3 or not all(math.isfinite(s) and s > 0 for s in scale):
        raise LayoutError(f"{urdf}: <{tag}> mesh scale must be 3 positive numbers")
    xyz, rpy = _origin(elem.find("origin"), urdf, tag)
    return MeshRef(path, xyz, rpy, scale)


def _float_text(elem: ET.Element | None, urdf: Path, field: str) -> float | None:
    if elem is None:
        return None
    text = elem.get("value") if elem.get("value") is not None else elem.text
    try:
        value = float(text)
    except (TypeError, ValueError) as e:
        raise LayoutError(f"{urdf}: {field} is not a number ({text!r})") from e
    if not math.isfinite(value):
        raise LayoutError(f"{urdf}: {field} is not finite ({text!r})")
    return value


def parse_urdf(urdf: Path | str) -> AssetSpec:
    """Read an EmbodiedGen single-link URDF.

    Args:
        urdf: path of the ``.urdf`` file.

    Returns:
        The asset's meshes, origins, friction (mu1/mu2 clipped to the ranges above) and
        optional mass.

    Raises:
        LayoutError: when the file is missing or not valid URDF, or a mesh is missing.
    """
    urdf = resolve_path(urdf, "URDF")
    if not urdf.is_file():
        raise LayoutError(f"{urdf}: URDF file does not exist. Fix: restore it or fix `assets`.")
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as e:
        raise LayoutError(f"{urdf}: not valid XML ({e}). Fix: repair the URDF.") from e
    links = root.findall("link") if root.tag == "robot" else []
    if len(links) != 1:
        raise LayoutError(
            f"{urdf}: expected a <robot> with exactly one <link>, found {len(links)}."
            " Fix: EmbodiedGen assets are single-link URDFs."
        )
    joints = [j.get("name", "?") for j in root.findall("joint")]
    if joints:
        raise LayoutError(
            f"{urdf}: has joints {joints}, which would be ignored (an asset is one rigid link)."
            " Fix: merge the parts into one link's meshes."
        )
    link = links[0]
    visual = _mesh(link, "visual", urdf)
    collision = _mesh(link, "collision", urdf)
    # a collision mesh whose hulls the simulator makes would fill a hollow: its convex parts,
    # probed in the object's frame as it rests (layout/collision.py)
    frame = rpy_to_matrix(collision.rpy) * np.asarray(collision.scale)
    parts = convex_collision(collision.path, tuple(frame.ravel()))
    if parts != collision.path:
        collision = dataclasses.replace(collision, path=parts, source=collision.path)
    mu1 = _float_text(link.find("collision/gazebo/mu1"), urdf, "collision/gazebo/mu1")
    mu2 = _float_text(link.find("collision/gazebo/mu2"), urdf, "collision/gazebo/mu2")
    mass = _float_text(link.find("inertial/mass"), urdf, "inertial/mass")
    if mass is not None and not MASS_RANGE[0] <= mass <= MASS_RANGE[1]:
        raise LayoutError(
            f"{urdf}: inertial/mass is {mass:g} kg, outside the plausible {MASS_RANGE[0]:g} to "
            f"{MASS_RANGE[1]:g} kg. Fix: give the mass in kilograms, or remove <mass> to use "
            f"{DEFAULT_DENSITY:g} kg/m^3 over the collision volume."
        )
    return AssetSpec(
        name=root.get("name", urdf.stem),
        urdf_path=urdf,
        visual=visual,
        collision=collision,
        static_friction=float(
            np.clip(DEFAULT_STATIC_FRICTION if mu1 is None else mu1, *STATIC_FRICTION_RANGE)
        ),
        dynamic_friction=float(
            np.clip(DEFAULT_DYNAMIC_FRICTION if mu2 is None else mu2, *DYNAMIC_FRICTION_RANGE)
        ),
        mass=mass,
    )


@dataclass(frozen=True)
class AssetGeometry:
    """Z-up geometry of an asset in its actor frame, computed once per file version."""

    vertices: np.ndarray  # (n, 3) collision vertices in the actor frame (Z-up)
    parts: tuple[np.ndarray, ...]  # vertices of each convex part, actor frame
    volume: float  # total volume of the convex parts, m^3

    @property
    def min_z(self) -> float:
        return float(self.vertices[:, 2].min())

    @property
    def max_z(self) -> float:
        return float(self.vertices[:, 2].max())

    def footprint(self) -> np.ndarray:
        """Counter-clockwise 2D convex hull ``(m, 2)`` of the vertices projected on XY."""
        return convex_hull_2d(self.vertices[:, :2])

    def top_hull(self, band: float) -> np.ndarray:
        """2D hull of the vertices within ``band`` metres of the highest point (the top)."""
        top = self.vertices[self.vertices[:, 2] >= self.max_z - band]
        return convex_hull_2d(top[:, :2])


def convex_hull_2d(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull ``(m, 2)`` of 2D points (qhull)."""
    # micrometre rounding drops the near-duplicates that floating-point rotation creates
    pts = np.unique(np.round(np.asarray(points, dtype=np.float64), 6), axis=0)
    if len(pts) < 3:
        return pts
    try:
        hull = pts[ConvexHull(pts).vertices]  # counter-clockwise in 2D
    except QhullError:  # all points collinear
        return pts[[0, -1]]
    # drop vertices within 10 micrometres of their predecessor: such edges have no usable normal
    keep = [0]
    for i in range(1, len(hull)):
        if np.hypot(*(hull[i] - hull[keep[-1]])) > 1e-5:
            keep.append(i)
    if len(keep) > 1 and np.hypot(*(hull[keep[-1]] - hull[keep[0]])) <= 1e-5:
        keep.pop()
    return hull[keep]


def _load_parts(mesh: MeshRef) -> list:
    """The convex parts the simulator makes of a collision mesh: SAPIEN's
    ``add_multiple_convex_collisions_from_file`` (assimp) takes one convex hull per object of
    an OBJ file (``o`` / ``g``), and one of the whole mesh otherwise; parts touching or apart
    in one object are one hull there, so they are one part here too."""
    import trimesh  # only where a mesh is read

    loaded = _load_parts_checked(mesh)
    if mesh.path.suffix.lower() != ".obj":
        return [loaded]
    objects = obj_objects(mesh.path)
    if len(objects) <= 1:
        return [loaded]
    return [trimesh.Trimesh(vertices=v, process=False) for v in objects if len(v) >= 4]


def _load_parts_checked(mesh: MeshRef, collision: bool = True):
    """The mesh file as one trimesh, refused when unreadable, empty or not finite; a heavy
    collision mesh is warned about once."""
    # trimesh (0.4 s to import) only where a mesh is read: `embodied-envs --help` starts without
    import trimesh

    other = _not_a_mesh(mesh.path)
    if other is not None:
        raise LayoutError(
            f"{mesh.path}: not a mesh file: its bytes are {other}. Fix: name the mesh file "
            "in the URDF's <mesh filename>, or re-export the mesh."
        )
    try:
        loaded = load_mesh(mesh.path)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise LayoutError(f"{mesh.path}: not a readable mesh ({e}). Fix: re-export it.") from e
    if (
        not isinstance(loaded, trimesh.Trimesh)
        or len(loaded.vertices) == 0
        or len(loaded.faces) == 0
    ):
        raise LayoutError(
            f"{mesh.path}: the mesh is empty (no vertices or faces). Fix: re-export the mesh."
        )
    vertices = np.asarray(loaded.vertices)
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices).all(1)).sum())
        raise LayoutError(
            f"{mesh.path}: {bad} vertices hold NaN or infinity (first: vertex "
            f"{int(np.flatnonzero(~np.isfinite(vertices).all(1))[0])}). Fix: re-export the mesh."
        )
    heavy = collision and len(loaded.faces) > HEAVY_COLLISION_FACES
    if heavy and mesh.named not in _WARNED_HEAVY:
        _WARNED_HEAVY.add(mesh.named)
        made = "" if mesh.source is None else f"its convex parts, made on load ({mesh.path}), have "
        warnings.warn(
            f"{mesh.named}: {made}{len(loaded.faces):,} faces. Collision meshes of EmbodiedGen"
            f" assets are convex parts of a few hundred faces; over {HEAVY_COLLISION_FACES:,}"
            " faces make building the env slow (about 37 s and 2.3 GB at 655k faces). Fix:"
            " simplify it (e.g. trimesh's simplify_quadric_decimation, or a convex decomposition).",
            stacklevel=2,
        )
    return loaded


_WARNED_HEAVY: set = set()


def _not_a_mesh(path: Path) -> str | None:
    """What the file at ``path`` holds when its first bytes show it is no mesh (an image, an
    archive; for an OBJ, a text format, any binary data), else None."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    for signature, kind in NOT_MESH_SIGNATURES.items():
        if head.startswith(signature):
            return kind
    if path.suffix.lower() == ".obj" and b"\0" in head:
        return "binary data, not text"
    return None


@dataclass(frozen=True)
class FileVersion:
    """One version of a file: its path, size and modification time (ns)."""

    path: str  # a string: keys are hashed and compared often
    size: int
    mtime_ns: int

    @classmethod
    def of(cls, path: str | os.PathLike) -> FileVersion:
        st = os.stat(path)
        return cls(os.fspath(path), st.st_size, st.st_mtime_ns)


def _read_only(value):
    """``value`` with every NumPy array in it (tuples, lists, dataclass fields) read-only."""
    if isinstance(value, np.ndarray):
        value.flags.writeable = False
    elif isinstance(value, tuple | list):
        for v in value:
            _read_only(v)
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            _read_only(getattr(value, f.name))
    return value


class FileCache:
    """Values computed from files, each kept under a key that holds the :class:`FileVersion`
    of every file it was read from: an edited file is read again, an unchanged one costs a
    ``stat``. Values are shared, so their arrays are made read-only. Least recently used
    values go beyond ``maxsize``."""

    def __init__(self, maxsize: int = 1024):
        self.maxsize = maxsize
        self._values: collections.OrderedDict = collections.OrderedDict()

    def get(self, key: tuple, compute: Callable[[], Any]) -> Any:
        """The value under ``key``, computed (once) by ``compute`` when missing."""
        if key in self._values:
            self._values.move_to_end(key)
            return self._values[key]
        value = self._values[key] = _read_only(compute())
        while len(self._values) > self.maxsize:
            self._values.popitem(last=False)
        return value

    def clear(self) -> None:
        self._values.clear()


ASSET_FILES = FileCache()  # this process's values read from asset files (URDFs, meshes)


def _geometry(collision: MeshRef) -> AssetGeometry:
    parts = []
    volume = 0.0
    for part in _load_parts(collision):
        verts = collision.to_link_frame(part.vertices)
        if len(verts) < 4:
            continue
        parts.append(verts)
        try:
            volume += float(ConvexHull(verts).volume)
        except Exception:  # a flat part has no volume; it still collides
            pass
    if not parts:
        raise LayoutError(
            f"{collision.named}: no convex part with at least 4 vertices."
            " Fix: export a closed collision mesh."
        )
    vertices = np.concatenate(parts)
    extent = vertices.max(0) - vertices.min(0)
    if extent.max() > MAX_OBJECT_SIZE:
        raise LayoutError(
            f"{collision.named}: the collision mesh is {' x '.join(f'{e:.4g}' for e in extent)} m"
            f" across x, y, z (with the URDF's scale {list(collision.scale)}), over "
            f"{MAX_OBJECT_SIZE:g} m: no object to grasp or set on a table; it reads as a mesh "
            "written in millimetres (or centimetres). Fix: export it in metres, or give its "
            '<mesh> scale="0.001 0.001 0.001" (centimetres: 0.01) in the URDF.'
        )
    thin = thickness(vertices)
    if thin < MIN_COLLISION_THICKNESS:
        raise LayoutError(
            f"{collision.named}: the collision mesh is flat ({extent.round(4).tolist()} m across"
            f" x, y, z; {thin:.4f} m at its thinnest, under {MIN_COLLISION_THICKNESS} m): the"
            " object would sink through its support. Fix: export a closed collision mesh with"
            " volume."
        )
    return AssetGeometry(vertices, tuple(parts), volume)


def asset_geometry(spec: AssetSpec, version: FileVersion | None = None) -> AssetGeometry:
    """Collision geometry of an asset in its Z-up actor frame (cached per file version;
    ``version``: the collision mesh's, when the caller has just read it)."""
    version = FileVersion.of(spec.collision.path) if version is None else version
    key = ("geometry", version, spec.collision)
    return ASSET_FILES.get(key, lambda: _geometry(spec.collision))
