"""EmbodiedGen's grasp annotations (``affordance_annot.json``) as the expert's grasp candidates.

EmbodiedGen's ``affordance-cli`` labels an asset's parts and writes, per part, simulation-checked
grasps of its Franka gripper model (GraspGen's)::

    {"affordances": [{"part_name": "handle", "graspable": true, "id": 0,
                      "grasp_group": {"grasp_7": {"confidence": 0.98, "position": [x, y, z],
                                                  "orientation": {"w": w, "xyz": [x, y, z]}}}}]}

A grasp is the pose of the gripper's root in the asset's link frame (the collision mesh with its
URDF origin and scale applied: the frame of the expert's grasp synthesis, ``solvers/grasps.py``):
z is the approach, the fingers close along x, and the point between the fingertips (ManiSkill's
``panda_hand_tcp``) lies ``GRASPGEN_TCP_DEPTH`` along z. The file is found where EmbodiedGen puts
it: the URDF's ``<custom_data><affordance><affordance_annot>`` (a path relative to the URDF), else
``affordance/affordance_annot.json`` or ``affordance_annot.json`` beside the URDF.

:func:`read_annotation` gives the grasps of the graspable parts in the synthesis' TCP terms;
``solvers/grasps.py`` keeps those that pass its own checks and ranks them first, by confidence.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ANNOT_NAME = "affordance_annot.json"
GRASPGEN_TCP_DEPTH = 0.1034  # m, the fingertips' centre along the gripper root's z (GraspGen)


class AffordanceError(ValueError):
    """An annotation file that cannot be read (names the file, the field and the fix)."""


@dataclass(frozen=True)
class Annotated:
    """Annotated grasps in the synthesis' TCP terms (object frame), best first.

    Attributes:
        centre, closing, approach: ``(n, 3)`` TCP position, closing (TCP y) and approach (TCP z).
        confidence: ``(n,)`` the annotation's confidence.
        part: ``(n,)`` the part name of each grasp.
    """

    centre: np.ndarray
    closing: np.ndarray
    approach: np.ndarray
    confidence: np.ndarray
    part: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.centre)


def annotation_path(urdf: Path) -> Path | None:
    """The asset's ``affordance_annot.json``, or None when it has none."""
    try:
        node = ET.parse(urdf).getroot().find(".//custom_data/affordance/affordance_annot")
    except (ET.ParseError, OSError):
        node = None  # the asset loader reports an unreadable URDF
    if node is not None and (node.text or "").strip():
        named = (urdf.parent / node.text.strip()).resolve()
        if not named.is_file():
            raise AffordanceError(
                f"{urdf}: <custom_data><affordance><affordance_annot> names {named}, which does "
                "not exist. Fix: correct the path (relative to the URDF) or remove the element"
            )
        return named
    for candidate in (urdf.parent / "affordance" / ANNOT_NAME, urdf.parent / ANNOT_NAME):
        if candidate.is_file():
            return candidate
    return None


def read_annotation(path: Path) -> Annotated:
    """Every grasp of the graspable parts in ``path``, by confidence (highest first).

    Raises:
        AffordanceError: naming the file and the field, for a file that is not such JSON.
    """

    def bad(where: str, why: str) -> AffordanceError:
        return AffordanceError(
            f"{path}: {where} {why}. Fix: re-run EmbodiedGen's affordance-cli on the asset, or "
            "remove the file (the expert then synthesises grasps from the collision mesh)"
        )

    try:
        payload = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise bad("the file", f"is not readable JSON ({e})") from e
    parts = payload.get("affordances") if isinstance(payload, dict) else None
    if not isinstance(parts, list):
        raise bad("'affordances'", "is missing or not a list")
    rows = []
    for i, part in enumerate(parts):
        if not isinstance(part, dict):
            raise bad(f"affordances[{i}]", "is not an object")
        if part.get("graspable") is False:
            continue
        group = part.get("grasp_group", {})
        if not isinstance(group, dict):
            raise bad(f"affordances[{i}].grasp_group", "is not an object")
        for key, g in group.items():
            where = f"affordances[{i}].grasp_group.{key}"
            try:
                conf = float(g["confidence"])
                pos = [float(v) for v in g["position"]]
                quat = [float(g["orientation"]["w"])] + [float(v) for v in g["orientation"]["xyz"]]
            except (KeyError, TypeError, ValueError) as e:
                why = f"lacks a number in confidence, position or orientation ({e})"
                raise bad(where, why) from e
            norm = math.sqrt(sum(v * v for v in quat))
            finite = all(map(math.isfinite, [*pos, *quat, conf]))
            if len(pos) != 3 or len(quat) != 4 or not finite:
                raise bad(where, "needs a finite confidence, 3 position and 4 quaternion numbers")
            if abs(norm - 1.0) > 1e-2:
                raise bad(where, f"has an orientation of norm {norm:.3f}, not a unit quaternion")
            rows.append((conf, pos, [v / norm for v in quat], str(part.get("part_name", i))))
    rows.sort(key=lambda r: -r[0])
    rot = np.array([_matrix_wxyz(q) for _, _, q, _ in rows]).reshape(-1, 3, 3)
    root = np.array([p for _, p, _, _ in rows], dtype=np.float64).reshape(-1, 3)
    return Annotated(
        centre=root + GRASPGEN_TCP_DEPTH * rot[:, :, 2],
        closing=rot[:, :, 0],
        approach=rot[:, :, 2],
        confidence=np.array([c for c, *_ in rows], dtype=np.float64),
        part=tuple(r[3] for r in rows),
    )


def _matrix_wxyz(q: list[float]) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
