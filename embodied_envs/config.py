"""Env settings that do not need the simulator: robots, the render camera, config files.

Config files (YAML or JSON) hold ``gym.make`` keyword arguments of ``PickEmbodiedGen-v1``::

    robot_init_qpos_noise: 0.0
    placement_limits: {reach_max: 0.70}
    goal_region: {height: [0.10, 0.20]}
    camera_cfg: {image_hw: [512, 512]}

:func:`load_config` merges several in order, a later file overriding an earlier one key by key
(dict-valued settings merge field by field); ``gym.make(..., config=[...])`` and the CLI's
``--config`` use it, and keywords given directly win over every file.

A relative path in a config file (``layout_file``: a file, folder or glob, or a list of them;
``PATH_KEYS``) is relative to that file's folder, so the file works from any working folder;
a path given directly as a keyword is relative to the working folder, as Python's are.
"""

from __future__ import annotations

import copy
import glob
import json
import math
import os
import stat
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import yaml

from embodied_envs.layout.assets import MAX_IMAGE_SIDE
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.placement.limits import GoalRegion, PlacementLimits
from embodied_envs.robots import NO_MODEL_NAMES, ROBOT_NAMES, ROBOTS, name_key

SUPPORTED_ROBOTS = list(ROBOTS)

# init_3dgs_quat's default (x y z w): +90 deg about x, turning a splat stored Y-up (as 3DGS and
# EmbodiedGen store them) Z-up; applied before the layout's background pose
SPLAT_Y_UP_TO_Z_UP = (0.7071, 0.0, 0.0, 0.7071)
MAX_SEED = 2**32 - 1  # ManiSkill seeds NumPy RandomStates, which take seeds in [0, 2**32)


def resolve_robot(layout_robot: str, robot_uids: str | None, source: str) -> str:
    """The ManiSkill robot uid to load: ``robot_uids`` when given (it wins over the layout),
    else the layout's ``relation.robot`` (a uid or another name of a supported robot, e.g.
    EmbodiedGen's "franka").

    Raises:
        ValueError: ``robot_uids`` is not a supported robot.
        LayoutError: without ``robot_uids``, a layout robot name with no supported model,
            naming the file, the name, the supported robots and the fix.
    """
    if robot_uids is not None:
        if robot_uids not in ROBOTS:
            raise ValueError(
                f"robot_uids={robot_uids!r} is not supported; use one of {SUPPORTED_ROBOTS}"
            )
        return robot_uids
    key = name_key(layout_robot)
    if key not in ROBOT_NAMES:
        why = (
            "which has no ManiSkill model here (EmbodiedGen writes it; nothing is substituted)"
            if key in NO_MODEL_NAMES
            else "which is not a supported robot name"
        )
        raise LayoutError(
            f'{source}: relation["robot"] is "{layout_robot}", {why}; supported robots: '
            f"{SUPPORTED_ROBOTS} (or their other names {sorted(set(ROBOT_NAMES) - set(ROBOTS))}"
            "). Fix: pass robot_uids=\"<one of them>\" to gym.make (it wins over the layout), "
            'or rename the robot node (relation["robot"] and its position) to one.'
        )
    return ROBOT_NAMES[key]


@dataclass(frozen=True)
class CameraSpec:
    """The human render camera (``camera_cfg``): eye, target, image size and vertical fov."""

    eye: tuple[float, float, float] = (0.9, 0.0, 1.1)
    target: tuple[float, float, float] = (0.0, 0.0, 0.9)
    height: int = 256
    width: int = 256
    fovy_deg: float = 75.0

    KEYS = ("camera_eye", "camera_target_pt", "image_hw", "fovy_deg")  # EmbodiedGen's names

    @classmethod
    def from_cfg(cls, cfg: Mapping | None) -> CameraSpec:
        """From EmbodiedGen's ``camera_cfg`` dict; missing keys take the defaults.

        Raises:
            ValueError: naming the field and the fix.
        """
        if cfg is None:
            return cls()
        unknown = set(cfg) - set(cls.KEYS)
        if unknown:
            raise ValueError(f"camera_cfg: unknown keys {sorted(unknown)}; known: {list(cls.KEYS)}")
        d = cls()
        eye = tuple(float(v) for v in cfg.get("camera_eye", d.eye))
        target = tuple(float(v) for v in cfg.get("camera_target_pt", d.target))
        hw = cfg.get("image_hw", (d.height, d.width))
        fovy = float(cfg.get("fovy_deg", d.fovy_deg))
        if len(eye) != 3 or len(target) != 3 or not all(map(math.isfinite, eye + target)):
            raise ValueError("camera_cfg: camera_eye and camera_target_pt need 3 finite numbers")
        if math.dist(eye, target) < 1e-6:
            raise ValueError("camera_cfg: camera_eye equals camera_target_pt. Fix: move the eye.")
        if len(hw) != 2 or not all(
            isinstance(v, int) and not isinstance(v, bool) and 0 < v <= MAX_IMAGE_SIDE for v in hw
        ):
            raise ValueError(
                f"camera_cfg: image_hw={list(hw)} must be two positive integers [height, width] "
                f"of at most {MAX_IMAGE_SIDE} px (larger images are refused: memory)"
            )
        if not 0 < fovy < 180:
            raise ValueError(f"camera_cfg: fovy_deg={fovy} must be in (0, 180)")
        return cls(eye, target, int(hw[0]), int(hw[1]), fovy)


# --- config files ----------------------------------------------------------------------------
# settings whose value is a dict, merged field by field, and the fields each accepts
NESTED_KEYS: dict[str, tuple[str, ...]] = {
    "placement_limits": tuple(f.name for f in fields(PlacementLimits)),
    "goal_region": tuple(f.name for f in fields(GoalRegion)),
    "camera_cfg": CameraSpec.KEYS,
}


# settings whose value is a path, or a list of paths: relative to the config file's folder
PATH_KEYS = ("layout_file",)


class ConfigError(ValueError):
    """A config file that cannot be used; names the file, the key and the fix."""


MAX_CONFIG_BYTES = 1 << 20  # a config file holds a few keywords: larger files are refused


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader without aliases (``*a`` expands without bound) and without
    duplicate keys (YAML would keep the last one silently)."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise ConfigError(
                f"line {event.start_mark.line + 1}: the alias *{event.anchor} is refused "
                "(aliases can expand without bound). Fix: write the value out"
            )
        return super().compose_node(parent, index)

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise ConfigError(
                    f"line {key_node.start_mark.line + 1}: the key {key!r} appears twice in one "
                    "mapping; YAML would silently keep the last. Fix: keep one"
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _unique_json_keys(pairs: list) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise ConfigError(f"the key {key!r} appears twice in one object. Fix: keep one")
        out[key] = value
    return out


def read_config_file(path: str | os.PathLike) -> dict:
    """One config file (``.yaml``/``.yml`` or ``.json``) as a dict: a regular file of at most
    ``MAX_CONFIG_BYTES``, without YAML aliases or repeated keys.

    Raises:
        ConfigError: unreadable, not a regular file, too large, not YAML/JSON, aliases or
            repeated keys, or not a mapping at the top.
    """
    path = Path(path)
    try:
        st = path.stat()
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(
                f"{path}: not a regular file (a device, FIFO or folder). Fix: give a YAML or "
                "JSON file"
            )
        if st.st_size > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"{path}: {st.st_size:,} bytes, over the {MAX_CONFIG_BYTES:,} bytes a config "
                "file may hold. Fix: keep only env keywords in it"
            )
        text = path.read_text()
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the config file ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file") from None
    kind = "JSON" if path.suffix.lower() == ".json" else "YAML"
    try:
        if kind == "JSON":
            data = json.loads(text, object_pairs_hook=_unique_json_keys)
        else:
            data = yaml.load(text, Loader=_StrictLoader)  # noqa: S506  (a safe loader)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None
    except (json.JSONDecodeError, yaml.YAMLError, RecursionError) as e:
        raise ConfigError(f"{path}: not valid {kind}: {e}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: a config file holds a mapping of env keywords (name: value), "
            f"got a {type(data).__name__}"
        )
    return data


def check_config_keys(config: Mapping, known: Sequence[str], source: str) -> None:
    """Refuse an unknown key, top level or inside a dict-valued setting, naming the known ones.

    Raises:
        ConfigError
    """
    unknown = sorted(set(config) - set(known))
    if unknown:
        raise ConfigError(
            f"{source}: unknown key(s) {unknown}; known: {sorted(known)}. Fix: spell the key "
            "as the gym.make keyword of PickEmbodiedGen-v1."
        )
    for key, allowed in NESTED_KEYS.items():
        value = config.get(key)
        if value is None:
            continue
        if not isinstance(value, Mapping):
            raise ConfigError(
                f"{source}: {key} must be a mapping of its fields {list(allowed)}, "
                f"got {type(value).__name__}"
            )
        bad = sorted(set(value) - set(allowed))
        if bad:
            raise ConfigError(f"{source}: {key}: unknown key(s) {bad}; known: {list(allowed)}")


def merge_config(base: Mapping, override: Mapping) -> dict:
    """``override`` over ``base``: dict-valued settings merge field by field, the rest replace."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if key in NESTED_KEYS and isinstance(out.get(key), Mapping) and isinstance(value, Mapping):
            out[key] = {**out[key], **copy.deepcopy(dict(value))}
        else:
            out[key] = copy.deepcopy(value)
    return out


def load_config(
    paths: str | os.PathLike | Sequence[str | os.PathLike] | None,
    known: Sequence[str],
    check: Callable[[str, Any], None] | None = None,
) -> dict:
    """Merge config files in order (later overrides earlier), checking every key.

    Args:
        paths: one file or a list; None gives ``{}``. Relative paths in a file (the values
            of ``PATH_KEYS``) are relative to its folder.
        known: accepted top-level keys (the env's: ``PickEmbodiedGenEnv.keywords()``).
        check: ``check(key, value)`` raises ``ValueError`` for a value of the wrong type or
            range (the env's: ``PickEmbodiedGenEnv.check_keyword``); named with the file.

    Raises:
        ConfigError: naming the file and the key.
    """
    if paths is None:
        return {}
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    merged: dict = {}
    for path in paths:
        data = read_config_file(path)
        check_config_keys(data, known, str(path))
        for key, value in data.items():
            try:
                if check is not None:
                    check(key, value)
            except ValueError as e:
                raise ConfigError(f"{path}: {e}") from None
        merged = merge_config(merged, _paths_from(data, Path(os.path.abspath(path)).parent))
    return merged


def _paths_from(data: dict, folder: Path) -> dict:
    """``data`` with each relative path of ``PATH_KEYS`` joined to ``folder`` (escaped where the
    path is a glob, so that the folder's name matches itself); ``~`` is a home folder."""

    def joined(value):
        if not isinstance(value, str) or Path(value).expanduser().is_absolute():
            return value  # a wrong type is named by the check of its key
        is_glob = any(c in value for c in "*?[")
        return os.path.join(glob.escape(str(folder)) if is_glob else folder, value)

    out = dict(data)
    for key in (k for k in PATH_KEYS if k in out):
        value = out[key]
        out[key] = [joined(v) for v in value] if isinstance(value, list) else joined(value)
    return out
