"""Value types of the env's keyword arguments, validated before anything is simulated."""

from __future__ import annotations

import math
from dataclasses import dataclass

from embodied_envs.layout.errors import LayoutError

# Layout robot names -> ManiSkill robot uids. An unknown name is an error unless the user
# passes robot_uids explicitly (EmbodiedGen silently fell back to panda).
ROBOT_REGISTRY = {
    "franka": "panda",
    "franka_panda": "panda",
    "panda": "panda",
    "panda_wristcam": "panda_wristcam",
}
SUPPORTED_ROBOTS = ["panda", "panda_wristcam"]


def resolve_robot(layout_robot: str, robot_uids: str | None, source: str) -> str:
    """The ManiSkill robot uid to load.

    Raises:
        LayoutError: when ``robot_uids`` is not given and the layout's robot is not registered.
    """
    if robot_uids is not None:
        if robot_uids not in SUPPORTED_ROBOTS:
            raise ValueError(
                f"robot_uids={robot_uids!r} is not supported; use one of {SUPPORTED_ROBOTS}"
            )
        return robot_uids
    key = layout_robot.lower().replace(" ", "_")
    if key not in ROBOT_REGISTRY:
        raise LayoutError(
            f'{source}: relation["robot"] is "{layout_robot}", which is not a registered robot '
            f"({sorted(ROBOT_REGISTRY)}). Fix: rename it, or pass robot_uids explicitly."
        )
    return ROBOT_REGISTRY[key]


@dataclass(frozen=True)
class CameraSpec:
    """The human render camera (``camera_cfg``): eye, target, image size and vertical fov."""

    eye: tuple[float, float, float] = (0.9, 0.0, 1.1)
    target: tuple[float, float, float] = (0.0, 0.0, 0.9)
    height: int = 256
    width: int = 256
    fovy_deg: float = 75.0

    @classmethod
    def from_cfg(cls, cfg: dict | None) -> CameraSpec:
        """From EmbodiedGen's ``camera_cfg`` dict; missing keys take the defaults.

        Raises:
            ValueError: naming the field and the fix.
        """
        if cfg is None:
            return cls()
        known = {"camera_eye", "camera_target_pt", "image_hw", "fovy_deg"}
        unknown = set(cfg) - known
        if unknown:
            raise ValueError(f"camera_cfg: unknown keys {sorted(unknown)}; known: {sorted(known)}")
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
            isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in hw
        ):
            raise ValueError(
                f"camera_cfg: image_hw={list(hw)} must be two positive integers [height, width]"
            )
        if not 0 < fovy < 180:
            raise ValueError(f"camera_cfg: fovy_deg={fovy} must be in (0, 180)")
        return cls(eye, target, int(hw[0]), int(hw[1]), fovy)
