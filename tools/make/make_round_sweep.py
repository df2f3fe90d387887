#!/usr/bin/env python
"""Round and rolling objects we did not design the expert on, as EmbodiedGen-format assets
and a layout around each (as ``make_grasp_zoo.py`` writes the zoo): balls of several radii
and masses, cylinders lying on their side, wheels on their edge and one lying flat.

Usage: python tools/make/make_round_sweep.py --out /tmp/round_sweep
then:  python tools/bench/bench_solver.py --episodes 6 --layout /tmp/round_sweep/layouts/*.json
"""

from __future__ import annotations

import argparse
from pathlib import Path

import trimesh
from make_grasp_zoo import DATA, cylinder, write_shapes


def ball(radius: float, subdivisions: int = 2) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    m.apply_translation((0, 0, radius))
    return m


def quarters(mesh: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    """The mesh cut in four by the vertical planes through its centre (as a convex
    decomposition such as CoACD's writes a round body: several convex parts; each is
    closed by its convex hull when written)."""
    c = mesh.bounds.mean(0)
    parts = []
    for sx in (1, -1):
        for sy in (1, -1):
            m = trimesh.intersections.slice_mesh_plane(mesh, (sx, 0, 0), c)
            parts.append(trimesh.intersections.slice_mesh_plane(m, (0, sy, 0), c))
    return parts


def cases() -> dict[str, tuple[list[trimesh.Trimesh], float, str]]:
    """name -> (convex parts, mass kg, description); sizes in cm in the names."""
    c = {}
    for r in (1.5, 2.0, 2.5, 3.0, 3.5):  # a rubber-ish ball: 0.05 kg at 2.2 cm
        c[f"ball_r{r * 10:.0f}"] = ([ball(r / 100)], round(0.05 * (r / 2.2) ** 3, 3), "a ball")
    c["ball_r25_light"] = ([ball(0.025)], 0.01, "a light ball")
    c["ball_r25_heavy"] = ([ball(0.025)], 0.5, "a heavy ball")
    c["ball_r10"] = ([ball(0.010)], 0.01, "a marble")
    c["ball_r12"] = ([ball(0.012)], 0.015, "a small ball")
    c["ball_r20_pingpong"] = ([ball(0.020)], 0.0027, "a ping-pong ball")
    c["ball_r25_smooth"] = ([ball(0.025, 4)], 0.05, "a smooth ball")
    c["ball_r25_parts"] = (quarters(ball(0.025, 3)), 0.05, "a ball in four convex parts")
    for r, length in ((1.5, 5), (1.5, 15), (2.5, 10), (3.0, 8), (3.0, 15), (4.0, 5)):
        parts = [cylinder(r / 100, length / 100, (0, 0, r / 100), axis="y")]
        c[f"side_cyl_r{r * 10:.0f}_l{length}"] = (parts, 0.15, "a cylinder lying on its side")
    for r, t in ((3.0, 1.0), (4.0, 1.5), (5.0, 2.0)):
        parts = [cylinder(r / 100, t / 100, (0, 0, r / 100), axis="y", sections=32)]
        c[f"wheel_r{r * 10:.0f}_t{t * 10:.0f}"] = (parts, 0.1, "a wheel standing on its edge")
    c["disc_flat_r30_t15"] = ([cylinder(0.03, 0.015, (0, 0, 0.0075), sections=32)], 0.1,
                              "a disc lying flat")  # fmt: skip
    return c


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, required=True)
    # the shipped assets by absolute path: the layouts load from any --out
    write_shapes(ap.parse_args(argv).out, cases(), "round shapes", shipped=DATA / "assets")


if __name__ == "__main__":
    main()
