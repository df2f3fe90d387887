"""Random splats for the splat tests."""

import numpy as np
import torch

from embodied_envs.splat.model import GaussianSplat
from embodied_envs.splat.sh import SH_C0


def random_splat(
    seed: int, n: int = 200, sh_degree: int = 0, spread: float = 1.0, normals: bool = False
) -> GaussianSplat:
    """Gaussians around the origin with varied size, shape, orientation and opacity."""
    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    sh = rng.normal(0.0, 0.3, (n, k, 3))
    sh[:, 0] = (rng.uniform(0.05, 0.95, (n, 3)) - 0.5) / SH_C0

    def t(a):
        return torch.as_tensor(a, dtype=torch.float32)

    return GaussianSplat(
        means=t(rng.uniform(-spread, spread, (n, 3))),
        quats_wxyz=t(rng.normal(size=(n, 4))),
        log_scales=t(np.log(rng.uniform(0.01, 0.25, (n, 3)))),
        opacity_logits=t(rng.normal(1.0, 2.0, n)),
        sh=t(sh),
        normals=t(rng.normal(size=(n, 3))) if normals else None,
    )
