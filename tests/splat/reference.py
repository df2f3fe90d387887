"""Brute-force splat renderer for tests: per pixel, all Gaussians, sorted, no tiles.

Written independently of ``embodied_envs.splat.rasterizer`` (numpy, float64, one Gaussian at a
time) and applying the 3DGS rasterization rules literally.
"""

from __future__ import annotations

import numpy as np

SH_C0 = 0.28209479177387814


def quat_to_matrix(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def render_reference(
    means,
    quats,
    scales,
    opacities,
    colors,
    w2c,
    fx,
    fy,
    cx,
    cy,
    width,
    height,
    background=(0.0, 0.0, 0.0),
):
    """Activated parameters in, (rgb (H, W, 3), alpha (H, W), depth (H, W)) out."""
    us, vs = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    color = np.zeros((height, width, 3))
    depth = np.zeros((height, width))
    trans = np.ones((height, width))
    done = np.zeros((height, width), dtype=bool)
    lim_x = 1.3 * max(cx, width - cx) / fx
    lim_y = 1.3 * max(cy, height - cy) / fy
    cam = (w2c[:3, :3] @ np.asarray(means, dtype=np.float64).T).T + w2c[:3, 3]
    order = np.argsort(cam[:, 2], kind="stable")
    for i in order:
        x, y, z = cam[i]
        if z <= 0.01 or abs(x / z) > lim_x or abs(y / z) > lim_y:
            continue
        rs = quat_to_matrix(np.asarray(quats[i], dtype=np.float64)) @ np.diag(scales[i])
        sigma = w2c[:3, :3] @ rs @ rs.T @ w2c[:3, :3].T
        jac = np.array([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]])
        cov = jac @ sigma @ jac.T + 0.3 * np.eye(2)
        inv = np.linalg.inv(cov)
        du = us - (fx * x / z + cx)
        dv = vs - (fy * y / z + cy)
        q = inv[0, 0] * du * du + 2 * inv[0, 1] * du * dv + inv[1, 1] * dv * dv
        alpha = np.minimum(0.99, opacities[i] * np.exp(-0.5 * q))
        active = (q <= 9.0) & (alpha >= 1.0 / 255.0) & ~done
        test_t = trans * (1.0 - alpha)
        stop = active & (test_t < 1e-4)
        done |= stop
        add = active & ~stop
        weight = np.where(add, alpha * trans, 0.0)
        color += weight[..., None] * np.asarray(colors[i])
        depth += weight * z
        trans = np.where(add, test_t, trans)
    rgb = color + trans[..., None] * np.asarray(background)
    return rgb, 1.0 - trans, depth
