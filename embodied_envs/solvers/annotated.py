"""EmbodiedGen's annotated grasps among the synthesised ones (``grasps.py`` step 5).

The annotations (``layout/affordance.py``) are checked like a synthesised grasp is: the TCP
inside the material, material between the open fingers that fits the opening, the swept gripper
clear of the object. Those that pass rank ahead of every synthesised grasp (simulation-checked
for this very asset), the ones clear by ``wide_margin`` first, each group by confidence.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from embodied_envs.layout.affordance import read_annotation
from embodied_envs.solvers.grasp_types import GraspConfig, Grasps
from embodied_envs.solvers.gripper import GripperModel, point_clearance, to_tcp


def with_annotations(
    grasps: Grasps, path: Path | None, cfg: GraspConfig, gripper: GripperModel
) -> Grasps:
    """``grasps`` with the annotated grasps of ``path`` (``layout/affordance.py``) that pass the
    synthesis' checks ahead of them: the TCP inside the material, material between the open
    fingers no wider than the opening allows (that width, pre-shaped, is the approach opening),
    the swept gripper clear of the object by ``margin``; those clear by ``wide_margin`` first,
    then by confidence."""
    if path is None:
        return grasps
    a = read_annotation(path)
    if not len(a):
        return grasps
    local = to_tcp(grasps.points, a.centre, a.closing, a.approach)  # (g, p, 3)
    z_base = gripper.finger_tip - gripper.finger_length
    between = (
        (np.abs(local[..., 0]) <= gripper.finger_width / 2)
        & (np.abs(local[..., 1]) <= gripper.opening / 2)
        & (local[..., 2] <= gripper.finger_tip)
        & (local[..., 2] >= z_base)
    )
    width = 2 * np.where(between, np.abs(local[..., 1]), 0.0).max(1)
    inside = np.zeros(len(a), bool)
    for p in grasps.planes:
        inside |= (a.centre @ p[:, :3].T + p[:, 3] < 0).all(1)
    opening = np.minimum(gripper.opening, width + 2 * cfg.preshape)
    gap = point_clearance(
        grasps.points, a.centre, a.closing, a.approach, gripper.boxes(cfg.sweep, opening)
    ).min(1)
    ok = (
        between.any(1) & inside & (gap > cfg.margin)
        & (width >= cfg.min_width) & (width <= gripper.opening - cfg.width_margin)
    )  # fmt: skip
    # ahead of every synthesised grasp (their scores are >= 0), roomy ones first
    score = (1.0 - a.confidence) - 4.0 + 2.0 * (gap <= cfg.wide_margin)
    n = len(grasps)
    old = grasps.annotated if grasps.annotated is not None else np.zeros(n, bool)
    merged = {
        "centre": (a.centre[ok], grasps.centre),
        "closing": (a.closing[ok], grasps.closing),
        "approach": (a.approach[ok], grasps.approach),
        "width": (width[ok], grasps.width),
        "opening": (opening[ok], grasps.opening),
        "score": (score[ok], grasps.score),
        "annotated": (np.ones(int(ok.sum()), bool), old),
    }
    merged = {k: np.concatenate(v) for k, v in merged.items()}
    order = np.argsort(merged["score"], kind="stable")
    return dataclasses.replace(grasps, **{k: v[order] for k, v in merged.items()})
