"""Spherical-harmonic colour constants shared by the PLY layout and the renderers."""

SH_C0 = 0.28209479177387814  # zeroth-order real spherical-harmonic constant
MAX_SH_DEGREE = 3


def sh_coeff_count(degree: int) -> int:
    """Spherical-harmonic coefficients per colour channel for a degree: (d + 1)^2."""
    return (degree + 1) ** 2
