"""Round and rolling objects (issue 36): the footprint grasp closes at a round body's widest
section, a sphere's grasps close through its centre, and a target that moved while the hand
approached is not grasped where it was but re-planned from where it lies."""

import numpy as np
import pytest
import sapien
from scipy.spatial import ConvexHull
from test_grasps import solve, spec_of

from embodied_envs.layout import asset_geometry
from embodied_envs.robots import PANDA_HAND
from embodied_envs.solvers.grasp_choice import grasp_frame
from embodied_envs.solvers.grasps import asset_grasps, posed_grasps
from embodied_envs.solvers.pick_place import SolverConfig


@pytest.mark.parametrize(
    ("name", "height"),
    [
        ("big_ball", 0.030),  # r 3 cm: its equator (was 2.5 cm: grasp_depth below the top)
        ("side_can", 0.028),  # r 2.8 cm on its side: its axis (was 2.1 cm)
        ("ball", 0.022),  # r 2.2 cm (was 1.5 cm: min_tcp_height)
        ("small_cube", 0.015),  # 2.8 cm box: no bulge, min_tcp_height as before
        ("bottle", 0.185),  # a neck: grasp_depth below the top as before
        ("wheel", 0.045),  # on its edge, closing across its flat faces: as before
    ],
)
def test_the_footprint_grasp_closes_at_a_round_bodys_widest_section(name, height):
    verts = asset_geometry(spec_of(name)).vertices
    cfg = SolverConfig(grasp_depth=PANDA_HAND.grasp_depth)  # the Panda's, as the solver sets it
    centre, closing = grasp_frame(verts, 0.0, cfg, np.array([0.0, 1.0, 0.0]))
    assert abs(centre[2] - height) < 0.0015, (name, centre[2])
    assert abs(closing[2]) < 1e-9


# the ball's grasps are sampled: 500 contact pairs over its 320 facets (35 mm2 each; a closing
# line runs along a facet's normal and passes the centre at the contact's distance from the
# facet's circumcentre), so about 45 lines pass within 1 mm and the 8 best (the 1-3 most central
# lines, 12 approaches each) lie far inside it, whatever sample a machine draws
NEAR_CENTRE = 0.001  # m


def facet_radii(vertices: np.ndarray) -> tuple[float, float]:
    """The smallest inscribed and the largest circumscribed radius of the hull's facets."""
    t = vertices[ConvexHull(vertices).simplices]
    a, b, c = (np.linalg.norm(t[:, i] - t[:, j], axis=1) for i, j in ((1, 2), (0, 2), (0, 1)))
    area = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1) / 2
    return float((2 * area / (a + b + c)).min()), float((a * b * c / (4 * area)).max())


def test_a_spheres_best_grasps_close_through_its_centre():
    """Each of the 8 best grasps of the big ball closes on a line within NEAR_CENTRE of its
    centre of mass; posed on a table, the first (which trades centring against the approach's
    tilt) crosses the centre's facet within its inscribed circle, each of the 8 within a facet's
    circumscribed one (the bound of every line along a facet's normal: posing keeps the lines),
    the first level (its equator)."""
    spec = spec_of("big_ball")
    grasps = asset_grasps(spec)
    centre = np.array([0.0, 0.0, 0.03])
    assert np.linalg.norm(grasps.com - centre) < 5e-4
    inscribed, circumscribed = facet_radii(asset_geometry(spec).parts[0])
    assert 0.002 < inscribed < circumscribed < 0.006  # the 320 facets of a 3 cm icosphere

    def offset(c, closing):  # the closing line's distance from the centre
        d = c - centre
        return np.linalg.norm(d - (d @ closing) * closing)

    for k in range(8):
        assert offset(grasps.centre[k], grasps.closing[k]) < NEAR_CENTRE, k
    posed = posed_grasps(grasps, np.eye(4), support_z=0.0, limit=8)
    assert len(posed) == 8
    for c, closing, _, _ in posed:
        assert offset(c, closing) < circumscribed
    assert offset(posed[0][0], posed[0][1]) < inscribed
    assert abs(posed[0][1][2]) < np.sin(np.radians(10))  # near level: through the equator


def test_a_target_that_moved_during_the_approach_is_grasped_where_it_lies():
    """The big ball is pushed 4 cm aside once the hand has reached its pre-grasp (as a ball
    rolls or a cylinder is knocked): the solver does not descend nor close where it was
    (miss ``moved (attempt 0)``), and grasps it from where it lies on the next attempt."""
    pushed, closed = [], []

    def patch(solver):
        per_env, set_gripper = solver._per_env, solver._set_gripper

        def pushing(stage, targets, *args, **kwargs):
            out = per_env(stage, targets, *args, **kwargs)
            if stage == "approach" and not pushed:
                pose = solver.base.obj.pose
                p, q = pose.p[0].cpu().numpy(), pose.q[0].cpu().numpy()
                solver.base.obj.set_pose(sapien.Pose(p + np.array([0.0, 0.04, 0.0]), q))
                pushed.append(p.tolist())
            return out

        def recorded(envs, value):
            if value == PANDA_HAND.action_closed:
                closed.append((len(solver.reports[0].misses), bool(envs[0])))
            set_gripper(envs, value)

        solver._per_env, solver._set_gripper = pushing, recorded

    success, result, _ = solve("big_ball", 0, patch)
    assert pushed, "the approach ran"
    assert result.reports[0].misses[:1] == ["moved (attempt 0)"], result.reports[0]
    assert closed[0] == (0, False), closed  # attempt 0: no env closed its fingers
    assert success, result.reports[0]

