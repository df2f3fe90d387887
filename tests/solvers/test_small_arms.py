"""The small arms (issue 50): grasps a five-joint arm can make (its approach in its vertical
plane, tilted within what it reaches, the fingers off the table), an object wider than the
jaws or heavier than the arm holds refused at gym.make in one line, and the expert on the
small-arm zoo."""

import dataclasses
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
from conftest import ROOT, solve_watching_close

import embodied_envs  # noqa: F401
from embodied_envs.internals import link_components
from embodied_envs.layout import LayoutError, LayoutPose, parse_urdf
from embodied_envs.layout.assets import asset_geometry
from embodied_envs.robots import ROBOTS
from embodied_envs.solvers import PickPlaceSolver
from embodied_envs.solvers.grasp_choice import GraspChoice, asset_spec, grasp_pose
from embodied_envs.solvers.grasps import GraspConfig, asset_grasps
from embodied_envs.solvers.gripper import GripperModel, box_corners, tcp_axes
from embodied_envs.solvers.planar import planar_grasps, table_gap
from embodied_envs.solvers.screw import SCREW_END_TOLERANCE

SMALL_ZOO = ROOT / "tests" / "data" / "small_zoo"
TOL = 1e-6  # unit vectors' products, in float64


@pytest.mark.parametrize("uid", ["so100", "koch-v1.1"])
def test_planar_grasps_lie_in_the_arms_plane_and_clear_the_table(uid):
    hand = ROBOTS[uid].hand
    gripper, cfg = GripperModel(**dict(hand.boxes)), GraspConfig(sweep=hand.approach_offset)
    spec = parse_urdf(SMALL_ZOO / "assets" / "marker" / "marker.urdf")
    grasps = asset_grasps(spec, cfg, gripper)
    base = np.array([0.0, 0.0])
    support = 0.74
    for yaw in (0.0, 0.7, 1.57):  # the marker along the arm's plane, askew, across it
        pose = LayoutPose.from_layout([0.2, 0.05, support, 0.0, 0.0, np.sin(yaw / 2),
                                        np.cos(yaw / 2)]).matrix()
        reach = lambda xy: hand.tilts_at(np.full(len(xy), 0.2))  # noqa: E731
        found = planar_grasps(grasps, pose, base, support, None, (30.0, 15.0, 0.0), reach,
                              cfg, gripper, 6)  # fmt: skip
        assert found, yaw
        for centre, closing, approach, opening in found:
            out = np.array([*centre[:2], 0.0]) / np.linalg.norm(centre[:2])
            across = np.cross([0.0, 0.0, 1.0], out)
            assert abs(approach @ across) < TOL  # within the arm's vertical plane
            assert abs(closing @ approach) < TOL
            tilt = np.degrees(np.arctan2(approach @ out, -approach[2]))
            assert -5.0 - TOL <= tilt <= 30.0 + TOL
            boxes = gripper.boxes(0.0, opening)[None, :2]
            low = box_corners(centre[None], tcp_axes(closing[None], approach[None]), boxes)
            assert low[..., 2].min() >= support + table_gap(cfg) - TOL



def test_planar_grasps_come_the_other_way_after_their_own():
    # the wrist roll's range may hold one way only (the Koch's eraser 0.24 m out: IK failed for
    # every pair's own way): the best pairs' own ways first, then the same grasps turned a half
    # turn about the approach, in the same order
    hand = ROBOTS["koch-v1.1"].hand
    gripper, cfg = GripperModel(**dict(hand.boxes)), GraspConfig(sweep=hand.approach_offset)
    grasps = asset_grasps(parse_urdf(SMALL_ZOO / "assets" / "marker" / "marker.urdf"), cfg, gripper)
    pose = LayoutPose.from_layout([0.2, 0.05, 0.74, 0.0, 0.0, 0.0, 1.0]).matrix()
    reach = lambda xy: hand.tilts_at(np.full(len(xy), 0.2))  # noqa: E731
    found = planar_grasps(grasps, pose, np.zeros(2), 0.74, None, (30.0, 15.0, 0.0), reach,
                          cfg, gripper, 3)  # fmt: skip
    assert len(found) == 6
    for own, other in zip(found[:3], found[3:], strict=True):
        assert np.allclose(other[0], own[0]) and np.allclose(other[2], own[2])
        assert np.allclose(other[1], -own[1]) and other[3] == own[3]

def test_the_reach_table_is_interpolated_between_its_rows():
    hand = ROBOTS["koch-v1.1"].hand  # rows (0.26 m: 0-60 deg), (0.29 m: 15-75 deg)
    lo, hi = hand.tilts_at(0.275)
    assert lo == pytest.approx(7.5) and hi == pytest.approx(67.5)
    lo, hi = hand.tilts_at(np.array([0.0, 0.26, 1.0]))  # the ends hold beyond the table
    assert np.allclose(lo, [0.0, 0.0, 30.0]) and np.allclose(hi, [0.0, 60.0, 75.0])


def test_each_planar_grasp_is_ranked_by_the_reach_at_its_own_centre():
    # accept8's 6.4 x 5.4 cm L block, seed 1: its centre 0.18 m from the Koch's pan axis, the
    # contact pairs on its far leg 2 cm further out, where the arm reaches only tilted; ranked
    # by the reach at the object's centre, all 12 options were top-down on that far leg and
    # none had IK; ranked by the reach at each grasp's centre, the near leg's come first
    hand = ROBOTS["koch-v1.1"].hand
    gripper, cfg = GripperModel(**dict(hand.boxes)), GraspConfig(sweep=hand.approach_offset)
    spec = parse_urdf(ROOT / "tests/data/small_sets/accept8/assets/l_block/l_block.urdf")
    grasps = asset_grasps(spec, cfg, gripper)
    base = np.array([0.3584, 0.2851])  # the layout's robot spot; its pan axis 6.8 cm ahead
    axis = np.array([0.306, 0.242])
    pose = LayoutPose.from_raw(np.array([0.1749, 0.1162, 0.80, 0.509, 0.0, 0.0, -0.861]))
    centre = pose.matrix()[:2, 3]
    tilts = (0.0, 15.0, 30.0)

    def first_offs(reach):
        found = planar_grasps(grasps, pose.matrix(), axis, 0.798, None, tilts, reach, cfg,
                              gripper, 6)  # fmt: skip
        assert found
        out = []
        for at, _, approach, _ in found[:6]:
            lo, hi = hand.tilts_at(np.linalg.norm(at[:2] - base))
            tilt = np.degrees(np.arctan2(np.linalg.norm(approach[:2]), -approach[2]))
            out.append(max(lo - tilt, tilt - hi, 0.0))
        return out

    own = first_offs(lambda xy: hand.tilts_at(np.linalg.norm(xy - base, axis=1)))
    assert max(own) == pytest.approx(0.0, abs=1e-6)  # every one within the reach at its centre
    whole = first_offs(lambda xy: hand.tilts_at(np.full(len(xy), np.linalg.norm(centre - base))))
    assert max(whole) > 1.0  # the ablation: ranked at the object's centre, some lie out of reach


def edited_cube_layout(tmp_path, old: str, new: str):
    """The SO-100's 3 cm cube layout with its cube's URDF text ``old`` replaced by ``new``."""
    assets = tmp_path / "assets"
    shutil.copytree(SMALL_ZOO / "assets" / "cube_30", assets / "cube_30")
    urdf = assets / "cube_30" / "cube_30.urdf"
    assert old in urdf.read_text()
    urdf.write_text(urdf.read_text().replace(old, new))
    layout = json.loads((SMALL_ZOO / "layouts" / "so100_cube_30.json").read_text())
    layout["assets"]["cube_30"] = str(assets / "cube_30")
    for node in ("background", "round_table"):
        layout["assets"][node] = str(ROOT / "embodied_envs" / "data" / "assets" / node)
    path = tmp_path / "edited_cube.json"
    path.write_text(json.dumps(layout))
    return path


REFUSED = {  # what the cube's URDF is given -> the refusal's text after the file's name
    "wider than the jaws": (
        'scale="1.0 1.0 1.0"', 'scale="3.0 3.0 3.0"',
        "the manipulated object 'cube_30' is 9.0 cm across at its narrowest; so100's jaws open "
        "8.4 cm (embodied_envs/robots.py), so it cannot grasp it. Fix: a smaller object, or a "
        "robot with a wider gripper (relation.robot or robot_uids=)"),
    # the SO-100's payload: its drives' 100 N m over g times its 0.30 m reach, 34.0 kg
    "heavier than the arm holds": (
        '<mass value="0.035"/>', '<mass value="40"/>',
        "the manipulated object 'cube_30' weighs 40 kg; so100's arm holds up at most 34 kg at "
        "its reach (its drives' force limit, embodied_envs/robots.py), so it cannot lift it. "
        "Fix: a lighter object (its URDF's inertial/mass), or a stronger robot (relation.robot "
        "or robot_uids=)"),
}  # fmt: skip


@pytest.mark.parametrize("why", list(REFUSED))
def test_an_object_the_arm_cannot_take_is_refused_at_make(tmp_path, why):
    old, new, message = REFUSED[why]
    path = edited_cube_layout(tmp_path, old, new)
    with pytest.raises(LayoutError) as e:
        gym.make("PickEmbodiedGen-v1", layout_file=str(path))
    assert str(e.value) == f"{path}: {message}"


def test_the_payload_is_the_drives_limit_at_the_reach(tmp_path):
    assert ROBOTS["so100"].payload == pytest.approx(100.0 / (9.81 * 0.30), rel=TOL)
    # 30 kg is within it: the env is made
    gym.make("PickEmbodiedGen-v1", layout_file=str(edited_cube_layout(
        tmp_path, '<mass value="0.035"/>', '<mass value="30"/>'))).close()  # fmt: skip


@pytest.mark.parametrize(("layout", "seed"), [("so100_marker", 1), ("koch_marker", 1)])
def test_the_expert_picks_a_lying_marker_on_each_small_arm(layout, seed):
    # before issue 50 neither arm had any grasp of a lying 2 cm marker ("approach": 0/6)
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(SMALL_ZOO / "layouts" / f"{layout}.json"),
                   control_mode="pd_joint_pos")  # fmt: skip
    env.reset(seed=seed)
    result = PickPlaceSolver(env, seed=seed).solve()
    assert result.reports[0].plan_failures == []
    assert bool(env.unwrapped.evaluate()["success"][0])
    env.close()


def test_where_no_options_descent_plans_the_consistent_expert_still_approaches():
    """The held-out 2.2 cm marker, SO-100 seed 1: from no approach option's end does the descent
    plan (the five-joint walks end 4-22 mm off); the consistent expert takes the first option
    whose approach plans, as the diverse one does, and the descent plans from where the arm
    then is (before: 'approach: ... what follows does not plan', seeds 0, 1, 3, 4 of 6)."""
    layout = SMALL_ZOO.parent / "small_zoo_hidden" / "layouts" / "so100_marker_22.json"
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout), control_mode="pd_joint_pos")
    try:
        env.reset(seed=1)
        result = PickPlaceSolver(env, seed=1).solve()
        assert result.reports[0].plan_failures == []
        assert bool(env.unwrapped.evaluate()["success"][0])
    finally:
        env.close()


@pytest.mark.parametrize("uid", ["so100", "koch-v1.1", "panda"])
def test_a_hand_with_a_still_jaw_takes_the_object_against_it(uid):
    """The grasp moved along its closing line so that the object between the jaws lies the
    arm's precision from the still jaw's face: a 2 cm cube, and the same cube with a leg (an
    L-shaped block) out past the fingers' side, which does not count."""
    hand, cfg = ROBOTS[uid].hand, GraspConfig()
    model = GripperModel(**dict(hand.boxes))
    solver = SimpleNamespace(robot_hand=hand, grasp_config=cfg, gripper_model=model)
    cube = np.array([[x, y, z] for x in (-0.01, 0.01) for y in (-0.01, 0.01)
                     for z in (0.74, 0.76)])  # fmt: skip
    out = model.finger_width / 2 + 0.005  # the leg's near side, past the fingers' side
    leg = np.array([[x, y, z] for x in (out, out + 0.01) for y in (-0.04, 0.04)
                    for z in (0.74, 0.76)])  # fmt: skip
    for closing, points in (([0.0, 1.0, 0.0], cube), ([1.0, 0.0, 0.0], cube),
                            ([0.0, 1.0, 0.0], np.concatenate([cube, leg]))):  # fmt: skip
        pose = grasp_pose(np.array([0.0, 0.0, -1.0]), np.array(closing), np.array([0, 0, 0.75]))
        [(moved, opening)] = GraspChoice._against_fixed_jaw(solver, [(pose, 0.05)], points)
        if not hand.fixed_jaw:  # jaws that close together: the grasp as it was
            assert moved is pose and opening == 0.05
            continue
        y = moved.to_transformation_matrix()[:3, 1]
        face = moved.p @ y + hand.fixed_jaw  # the still jaw's inner face along the closing
        near = (cube @ y).max() if hand.fixed_jaw > 0 else (cube @ y).min()
        assert abs(face - near) == pytest.approx(cfg.margin, abs=TOL)
        assert np.allclose(moved.q, pose.q, atol=TOL) and moved.p[2] == pytest.approx(0.75)
        # the moving jaw preshape past the 2 cm cube's far side, at most its widest
        widest = hand.action_openings[-1][0]
        assert opening == pytest.approx(min(widest, cfg.margin + 0.02 + cfg.preshape))


def test_the_koch_takes_a_thin_domino_between_its_jaws_faces():
    """A 0.8 cm domino (held-out layout, seed 0): the open fingers held the obstacle margin
    above the table as well (5 mm) left the Koch's tips 3 mm of it, the moving jaw's tip rode
    over its edge and shut (three misses). Held the descent's error above it, the tips stand
    in its lower half at the close, the jaw closes on its 2.4 cm side and it is held."""
    layout = ROOT / "tests" / "data" / "small_zoo_hidden" / "layouts" / "koch_domino.json"
    tip = dict(ROBOTS["koch-v1.1"].hand.boxes)["finger_tip"]

    def look(solver):
        u = solver.base
        pose = LayoutPose.from_raw(u.task_scene.movers[0].pose.raw_pose[0].numpy())
        z = pose.transform_points(asset_geometry(asset_spec(u.layouts[0], "domino")).vertices)[:, 2]
        tips = solver._tcp().p[0, 2].item() - tip
        return solver._fingers()[0, 0], tips - z.min(), z.max() - z.min()

    env, solver, closed = solve_watching_close(layout, 0, look)
    u = env.unwrapped
    assert bool(u.evaluate()["success"][0]) and not solver.reports[0].misses
    (_, tips, height), (jaw, _, _) = closed[0]  # the tips and the domino before, the jaw after
    assert 0.3 < jaw < 0.5  # rad: closed on 2.2-2.6 cm (robots.KOCH_HAND.action_openings)
    assert tips < height / 2  # the tips in its lower half, not 3 mm off its top
    assert tips > -SCREW_END_TOLERANCE  # the descent ends at most that far low
    env.close()


SO100_BLOCK = ROOT / "embodied_envs" / "data" / "layouts" / "so100_block.json"


def so100_block_episode(seed: int, mode: str = "pd_joint_pos", **make):
    """so100_block's episode ``seed`` by the expert in ``mode`` (the env made with ``make``
    too): (success, solver, the wrist roll's joint position per control step)."""
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(SO100_BLOCK), control_mode=mode, **make)
    env.reset(seed=seed)
    solver = PickPlaceSolver(env, seed=seed)
    rolls, step = [], solver._step_once

    def watched(action):
        step(action)
        rolls.append(solver._qpos()[0, 4])

    solver._step_once = watched
    solver.solve()
    success = bool(env.unwrapped.evaluate()["success"][0])
    env.close()
    return success, solver, np.array(rolls)


def test_the_wrist_rolls_the_short_way_to_a_two_jaw_grasp():
    """A two-jaw grasp turned by pi about its approach is the same grasp: of the two the
    expert takes the one its arm reaches in fewer steps (so100_block seed 5 turned the SO-100's
    wrist roll 4.4 rad the long way, 10 s in pd_joint_delta_pos; the other way 1.1 rad)."""
    success, _, rolls = so100_block_episode(5)
    assert success
    assert np.abs(np.diff(rolls)).sum() < 1.6  # rad over the episode


def test_the_hand_rises_out_of_a_start_among_the_obstacle_points():
    """so100_block seed 10 placed without the arm's rest boxes (``rest_arm=None``, as an arm
    started elsewhere than its rest may meet): the can stands under the SO-100's moving jaw,
    inside the obstacle points' 1 cm spheres (no contact in the simulation), where no path may
    start: the hand first rises straight up, then plans, and the episode succeeds. With the
    boxes (the default) the can stands clear of the jaws and the start is free."""
    for rest_arm, collides in ((None, True), (ROBOTS["so100"].rest_arm, False)):
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(SO100_BLOCK),
                       placement_limits=dict(rest_arm=rest_arm))  # fmt: skip
        env.reset(seed=10)
        solver = PickPlaceSolver(env, seed=10)
        assert solver._start_collides(0, solver._qpos()[0]) == collides
        env.close()
    success, solver, _ = so100_block_episode(10, placement_limits=dict(rest_arm=None))
    assert success and not solver.reports[0].plan_failures


def test_the_so100_takes_its_block_in_pd_joint_delta_pos():
    """In pd_joint_delta_pos each SO-100 joint moves at most 0.45 rad/s: seed 5 turns its base
    2.7 rad and ended at the 500th step with a 5 cm lift (50-90 steps); lifted 2 cm first
    (``Hand.lift_heights``), the carry rises the rest while the base turns (463-466 steps on
    two machines). Seed 7 (492 steps on one machine, its grasp missed twice on another) is
    left to the benchmark: a test pins no episode that close to the step limit."""
    success, solver, _ = so100_block_episode(5, "pd_joint_delta_pos")
    assert success and not solver.reports[0].misses and solver.steps < 490


DEV1 = ROOT / "tests" / "data" / "small_sets" / "dev1" / "layouts"


def drawn_episode(folder: str, name: str, seed: int, solver_class=PickPlaceSolver, **make):
    """The expert's episode ``seed`` in ``pd_joint_pos`` on the drawn set ``folder``'s layout
    ``name`` (``tests/data/small_sets``, ``tools/make/make_small_sets.py``), the env made with
    ``make`` too: (success, solver)."""
    layout = DEV1.parents[1] / folder / "layouts" / f"{name}.json"
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout), control_mode="pd_joint_pos",
                   **make)  # fmt: skip
    env.reset(seed=seed)
    solver = solver_class(env, seed=seed)
    solver.solve()
    success = bool(env.unwrapped.evaluate()["success"][0])
    env.close()
    return success, solver


@pytest.mark.parametrize("folder, arm", [("dev1", "so100"), ("dev1", "koch"), ("accept2", "so100")])
def test_a_flat_l_shaped_block_is_taken(folder, arm):
    """The development set's L-shaped block (bars 1.6 cm wide and 1.1 cm high, the other leg
    3.8 cm out): the hand measured it across its whole extent, the leg's, and missed every
    seed (the SO-100's still jaw 2.9 cm off the bar, its jaw stopping short; the Koch's moving
    jaw pushing it 1.4 cm across the table). Its extent between the jaws is the bar's. The
    acceptance set's (a 2.2 cm bar 1.5 cm high) is closed on along its 4.5 cm leg, where the
    SO-100's jaw pushes it 6 mm onto its still jaw: 40 steps of its gentle close ended 3 mm
    into that push (``SolverConfig.close_steps``)."""
    success, solver = drawn_episode(folder, f"{arm}_l_block", 0)
    assert success and not solver.reports[0].misses


def koch_with_maniskill_pads(monkeypatch):
    """The Koch's entry with ManiSkill 3.0.1's own pads (its class's friction 0.3) and the
    squeeze its expert had on them (0.01 rad)."""
    koch = ROBOTS["koch-v1.1"]
    hand = dataclasses.replace(koch.hand, squeeze=0.01)
    koch = dataclasses.replace(koch, pad_friction=None, hand=hand)
    monkeypatch.setitem(ROBOTS, "koch-v1.1", koch)


def tilted_cones() -> dict:
    spec = SimpleNamespace(dynamic_friction=0.6)  # a block's
    cones = {}
    for uid in ("so100", "koch-v1.1", "panda"):
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(DEV1 / "so100_cube.json"),
                       robot_uids=uid)  # fmt: skip
        solver = SimpleNamespace(base=env.unwrapped, grasp_config=GraspConfig())
        cones[uid] = GraspChoice.asset_config(solver, spec).tilted_cone_deg
        env.close()
    return cones


def test_the_tilted_cone_follows_the_pads_friction(monkeypatch):
    """A lying triangular prism needs each face's normal 30 degrees off the closing line: the
    pads of friction 2 (the SO-100's and the Panda's from ManiSkill, the Koch's from its
    ``Robot.pad_friction``) allow it on a block's 0.6; ManiSkill's own Koch pads (0.3) do not."""
    cones = tilted_cones()
    assert all(cone > 30 for cone in cones.values()), cones
    koch_with_maniskill_pads(monkeypatch)
    cones = tilted_cones()
    assert cones["so100"] > 30 and cones["panda"] > 30 and 15 < cones["koch-v1.1"] < 30


def pad_frictions(layout: Path) -> dict:
    """Each link's collision shapes' (static, dynamic) frictions, over every shape."""
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout))
    out = {}
    for link in env.unwrapped.main_agent.robot.links:
        shapes = [s for obj in link_components(link) for s in obj.collision_shapes]
        out[link.name] = {(round(s.physical_material.static_friction, 4),
                           round(s.physical_material.dynamic_friction, 4)) for s in shapes}
    env.close()
    return out


def test_the_koch_jaws_have_pads_of_friction_2(monkeypatch):
    """The links ManiSkill's Koch gives its ``gripper`` material (``link_6``, ``gripper``; 0.3
    there, the Panda's and the SO-100's 2) get ``pad_friction`` 2 at load; its other links keep
    ManiSkill's. With the entry's ``pad_friction`` None the jaws keep ManiSkill's 0.3."""
    ours = pad_frictions(ROOT / "layouts" / "koch_block.json")
    assert ours["link_6"] == ours["gripper"] == {(2.0, 2.0)}
    assert ours["link_5"] != {(2.0, 2.0)}
    koch_with_maniskill_pads(monkeypatch)
    theirs = pad_frictions(ROOT / "layouts" / "koch_block.json")
    assert theirs["link_6"] == theirs["gripper"] == {(0.3, 0.3)}
    assert theirs["link_5"] == ours["link_5"]


def test_pads_set_on_an_arm_without_pads_are_refused():
    """A robot entry with ``pad_friction`` whose ManiSkill class gives no link the ``gripper``
    material is refused in one line naming robots.py, the robot and the fix."""
    from embodied_envs.envs.agents import set_pads

    entry = dataclasses.replace(ROBOTS["koch-v1.1"], pad_friction=1.5)
    agent = SimpleNamespace(urdf_config={}, robot=SimpleNamespace(links=[]))
    with pytest.raises(ValueError, match=r"robots.py: koch-v1.1's pad_friction=1.5 .*None"):
        set_pads(agent, entry)
    set_pads(agent, dataclasses.replace(entry, pad_friction=None))  # ManiSkill's: nothing to do


def test_the_koch_takes_a_lying_prism_on_its_pads(monkeypatch):
    """accept11's 2 cm lying triangular prism (seed 0): faces 30 degrees off the closing line
    need friction 0.58; the Koch's pads (2, averaged with the prism's 0.6 by PhysX) hold it. On
    ManiSkill's own pads (0.3: 24 degrees) the expert refuses it (no grasp: plan stage
    ``grasp``) and the episode fails."""
    success, solver = drawn_episode("accept11", "koch_tri_prism", 0)
    assert success and not solver.reports[0].plan_failures, solver.reports[0]
    koch_with_maniskill_pads(monkeypatch)
    success, solver = drawn_episode("accept11", "koch_tri_prism", 0)
    assert not success
    assert solver.reports[0].plan_failures[0].startswith("grasp"), solver.reports[0]


def test_a_hex_pencil_lying_on_a_face_is_taken_across_its_slanted_faces():
    """The drawn set accept3's hex pencil (2.3 cm across its corners) lies on a face: its
    pairs of faces close vertically or 30 degrees off vertical, which the SO-100's hand,
    approaching within its arm's plane at most 45 degrees off straight down, cannot take (no
    option: "approach" failed every seed). Its grasps then include pairs on rays tilted within
    its pads' friction, across the two upper slanted faces."""
    success, solver = drawn_episode("accept3", "so100_hex_pencil", 2)
    assert success and not solver.reports[0].plan_failures


@pytest.mark.parametrize("seed", [1, 4])
def test_the_koch_takes_a_ball_at_its_equator(seed, monkeypatch):
    """The Koch grasps 5 mm under an object's top (its knuckle): a 2.9 cm ball taken there
    was squeezed down out of its jaws (accept4, seeds 1 and 4: three grasp misses each). A
    body that bulges is taken at its widest section (``grasps.widest_height``), here the
    equator, which lies less than 1.5 cm (``min_tcp_height``) above the table."""
    import embodied_envs.solvers.grasp_choice as choice

    heights = []
    frame = choice.grasp_frame

    def recorded(vertices, support, cfg, current_y):
        centre, closing = frame(vertices, support, cfg, current_y)
        heights.append((centre[2], vertices[:, 2].min(), vertices[:, 2].max()))
        return centre, closing

    monkeypatch.setattr(choice, "grasp_frame", recorded)
    success, solver = drawn_episode("accept4", "koch_ball", seed)
    assert success and not solver.reports[0].misses, solver.reports[0]
    z, bottom, top = heights[0]
    assert abs(z - (bottom + top) / 2) < 0.002, (z, bottom, top)
    assert top - z > 0.012  # not 5 mm under the top


class NeverFirm(PickPlaceSolver):
    """The expert as it was: a retry closes as the first attempt did."""

    @property
    def firm(self):
        return np.zeros(self.num_envs, bool)

    @firm.setter
    def firm(self, value):
        pass


def test_the_koch_squeezes_lightly_on_its_pads(monkeypatch):
    """accept9's cone on the Koch (seed 2): on pads of friction 2 its squeeze of 3 mrad holds
    the cone to the goal; on the same pads at 0.01 rad (its squeeze on ManiSkill's pads) its
    hand ended 12 cm off its planned lift (the arm giving way) and the cone short of the goal."""
    success, solver = drawn_episode("accept9", "koch_cone", 2)
    assert success and not solver.reports[0].misses, solver.reports[0]
    koch = ROBOTS["koch-v1.1"]
    hand = dataclasses.replace(koch.hand, squeeze=0.01)
    monkeypatch.setitem(ROBOTS, "koch-v1.1", dataclasses.replace(koch, hand=hand))
    success, solver = drawn_episode("accept9", "koch_cone", 2)
    assert not success


def test_a_grip_that_slipped_presses_on_the_retry(monkeypatch):
    """accept4's hex pencil on the Koch with ManiSkill's own pads (0.3; seed 0): the first
    close sets its squeeze while the jaw still closes, the pencil held by 0.7 N slips at the
    lift; the retry presses until the jaw rests (``PickPlaceSolver.firm``) and carries it.
    Retrying as the first attempt closed, every attempt slips. On its pads of friction 2
    (``Robot.pad_friction``) the first attempt holds it."""
    success, solver = drawn_episode("accept4", "koch_hex_pencil", 0)
    assert success and not solver.reports[0].misses, solver.reports[0]
    koch_with_maniskill_pads(monkeypatch)
    success, solver = drawn_episode("accept4", "koch_hex_pencil", 0)
    assert success and solver.reports[0].misses == ["grasp (attempt 0)"], solver.reports[0]
    assert solver.firm[0]
    success, solver = drawn_episode("accept4", "koch_hex_pencil", 0, NeverFirm)
    assert not success
    misses = solver.reports[0].misses
    assert misses[:2] == ["grasp (attempt 0)", "grasp (attempt 1)"], misses


def test_a_small_arm_has_room_beside_its_mover_and_says_when_it_has_none():
    """accept6's 2.1 cm ball, seed 1: placed 1 cm from an 8.2 cm tin (the placement clearance),
    no grasp of the Koch's hand cleared the tin, and the solver approached nothing and said
    nothing ("approach: "). Now the episode says why in one line; with the small arms' movers'
    clearance (2 cm, the default) the ball stands clear and is taken."""
    then = dict(mover_clearance=None, rest_arm=None)  # the placement then: no rest boxes either
    crowded, solver = drawn_episode("accept6", "koch_ball", 1, placement_limits=then)
    assert not crowded
    assert solver.reports[0].plan_failures == [
        "grasp: none clears the table and the other objects (the hand's boxes, GraspConfig's "
        "margins)"
    ]
    success, solver = drawn_episode("accept6", "koch_ball", 1)
    assert success and not solver.reports[0].plan_failures


def test_a_five_joint_arms_plane_passes_through_its_base_joint():
    """A five-joint arm points its hand in a vertical plane through its base joint's axis,
    which stands 4.5 cm (SO-100) and 6.8 cm (Koch) ahead of its base link's origin. The
    planner's plane went through the origin: accept7's cube, seed 2, 0.229 m out and 54
    degrees off the Koch's heading, lay 13 degrees out of that plane, and the IK reached none
    of its 14 grasps ("approach: ... IK failed"). ``_pan_axis`` is the joint's axis (the
    simulator's joint pose, at any base turn), the Panda's exactly its base's origin."""

    for layout in (DEV1.parents[1] / "accept7" / "layouts" / "so100_cube.json",
                   DEV1.parents[1] / "accept7" / "layouts" / "koch_cube.json",
                   ROOT / "embodied_envs" / "data" / "layouts" / "default.json"):  # fmt: skip
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout))
        env.reset(seed=2)
        solver = PickPlaceSolver(env, seed=2)
        robot = env.unwrapped.agent.robot
        joint = robot.get_active_joints()[0].get_global_pose().p[:, :2].numpy()
        np.testing.assert_allclose(solver._pan_axis(), joint, atol=1e-5)
        root = robot.pose.raw_pose[:, :2].numpy()
        if layout.name == "koch_cube.json":  # its reach band is centred on this axis
            u = env.unwrapped
            spot = u.layouts[0].pose(u.layouts[0].robot)
            centre = u.placement_limits.reach_centre(np.array(spot.p[:2]), np.float64(spot.yaw))
            np.testing.assert_allclose(solver._pan_axis()[0], centre, atol=1e-3)
        if "default" in layout.name:
            assert (solver._pan_axis() == root).all()
        else:
            assert np.linalg.norm(solver._pan_axis() - root) > 0.04
            qpos = robot.get_qpos().clone()
            qpos[0, 0] += 1.0
            robot.set_qpos(qpos)
            np.testing.assert_allclose(solver._pan_axis(), joint, atol=1e-5)
        env.close()
    success, solver = drawn_episode("accept7", "koch_cube", 2)
    assert success and not solver.reports[0].plan_failures


class LetsGo(PickPlaceSolver):
    """The expert as it was: the jaw's target stays where the grasp set it."""

    def _keep_grip(self):
        pass


class Watched(PickPlaceSolver):
    """The expert, the jaw's target's lead on the jaw (action) seen at the episode's end."""

    def solve(self):
        out = super().solve()
        self.lead_at_end = float(self._jaw_action()[0] - self.gripper[0])  # the jaw closes to -
        return out


def test_a_held_jaw_keeps_pressing_through_the_carry():
    """accept10's 2.4 cm hex pencil on the SO-100 (seed 0), held at its side edges: the jaw's
    target, set 2 mrad past the jaw at the grasp, was reached as the contacts settled (0.3
    mrad left: 3 N, then 0 N as the carry's base turn began) and the pencil fell out, at every
    attempt. Kept ``Hand.grip_lead`` past the jaw at every step, the jaw presses on and the
    pencil is carried."""
    hand = ROBOTS["so100"].hand
    assert hand.grip_lead > 0 and ROBOTS["panda"].hand.grip_lead == 0
    success, solver = drawn_episode("accept10", "so100_hex_pencil", 0, Watched)
    assert success and not solver.reports[0].misses, solver.reports[0]
    assert solver.gripping[0]  # still holding on at the goal, its target leading the jaw
    assert solver.lead_at_end == pytest.approx(hand.grip_lead, abs=5e-4)
    success, solver = drawn_episode("accept10", "so100_hex_pencil", 0, LetsGo)
    assert not success
    assert solver.reports[0].misses[:2] == ["carry (attempt 0)", "carry (attempt 1)"]


class AngleRule(PickPlaceSolver):
    """The expert as it was: a gentle close stops at ManiSkill's grasp rule, its angle too."""

    def _pressing(self):
        return self._grasping()


def test_a_close_stops_where_both_jaws_press_at_any_angle():
    """accept9's lying triangular prism on the SO-100 (seed 0): its faces, 30 degrees off the
    closing line, push the moving jaw 116-121 degrees off its opening direction, past the
    110 of ManiSkill's rule (the env's ``is_grasped``). Waiting for that rule the close squeezed
    on, the prism wedged under the jaws and every attempt missed; stopping where both jaws
    press (``PickPlaceSolver._pressing``) the prism is carried."""
    success, solver = drawn_episode("accept9", "so100_tri_prism", 0)
    assert success and not solver.reports[0].misses, solver.reports[0]
    success, solver = drawn_episode("accept9", "so100_tri_prism", 0, AngleRule)
    assert not success
    assert solver.reports[0].misses[:2] == ["grasp (attempt 0)", "grasp (attempt 1)"]


class LightSqueeze(PickPlaceSolver):
    """The expert as it was: a wedge held as any grasp, 2 mrad past where the jaw first pressed."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.robot_hand = dataclasses.replace(self.robot_hand, wedge_squeeze=0.0)


def test_a_short_wedge_is_held_by_the_wedge_squeeze():
    """accept11's 2 cm lying triangular prism (1.7 cm tall) on the SO-100 (seed 0): its faces,
    30 degrees off the closing line, are pressed at an angle the robot's grasp rule does not
    count (a wedge). Held 2 mrad past where the jaw first pressed (``Hand.squeeze``: 1-2 N),
    the hand's first lift steps rocked the still jaw 0.6 mm off its face and the prism stayed
    on the table at every attempt; held ``Hand.wedge_squeeze`` (8 mrad) past, it is carried
    (here at the second attempt)."""
    hand = ROBOTS["so100"].hand
    assert hand.wedge_squeeze == pytest.approx(0.008) and hand.squeeze == pytest.approx(0.002)
    success, solver = drawn_episode("accept11", "so100_tri_prism", 0)
    assert success and len(solver.reports[0].misses) <= 1, solver.reports[0]
    success, solver = drawn_episode("accept11", "so100_tri_prism", 0, LightSqueeze)
    assert not success
    assert solver.reports[0].misses == [f"grasp (attempt {k})" for k in range(3)]
