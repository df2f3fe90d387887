"""The gripper boxes' clearance (``solvers/gripper.py``): one box bound at a time gives the
float32 values of the definition (``outside`` of every box, the least), bit for bit."""

import numpy as np

from embodied_envs.solvers.gripper import (
    GripperModel,
    outside,
    pair_clearance,
    point_clearance,
    tcp_axes,
    to_tcp,
)


def grasps(rng, n):
    closing = rng.normal(size=(n, 3))
    closing /= np.linalg.norm(closing, axis=1, keepdims=True)
    approach = np.cross(closing, rng.normal(size=(n, 3)))
    approach /= np.linalg.norm(approach, axis=1, keepdims=True)
    return rng.normal(0, 0.03, (n, 3)), closing, approach


def test_point_and_pair_clearance_are_the_definition_bit_for_bit():
    rng = np.random.default_rng(3)
    centre, closing, approach = grasps(rng, 40)
    points = rng.normal(0, 0.06, (300, 3))
    opening = rng.uniform(0.01, 0.08, 40)
    for boxes in (GripperModel().boxes(0.08, opening), GripperModel().boxes(0.0)[None]
                  .repeat(40, 0)):  # fmt: skip
        local = to_tcp(points, centre, closing, approach)  # (g, p, 3)
        want = outside(local[:, :, None], boxes[:, None]).min(2)
        got = point_clearance(points, centre, closing, approach, boxes)
        assert got.dtype == np.float32 and np.array_equal(got, want)
        assert (want < 0).any() and (want > 0.01).any()  # inside some boxes, far from others
        g, k = rng.integers(0, 40, 5000), rng.integers(0, 300, 5000)
        rot = tcp_axes(closing, approach)
        pairs = np.einsum("pk,pjk->pj", points[k] - centre[g], rot[g])
        want = outside(pairs[:, None], boxes[g]).min(-1)
        got = pair_clearance(points, centre, rot, boxes, g, k)
        assert got.dtype == np.float32 and np.array_equal(got, want)
