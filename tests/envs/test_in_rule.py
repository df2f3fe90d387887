""""In" as a person means it, by set poses in the env (the movers teleported, nothing
stepped): a mover resting on the receptacle's inner floor, or on another mover in it, is in
it however tall it is; one on the rim, leaning on the outer wall, held above or beside it is
not, and ``task_reader.unmet()`` says which condition fails. The layouts are
``tests/data/upright`` (``tools/make/make_upright.py``): cans and bottles, 12 and 22 cm tall,
in bowls 4.4-5.9 cm deep and a 1.4 cm tray, and the grasp zoo's shallow bowl."""

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch
from conftest import ROOT
from mani_skill.utils.structs import Pose

from embodied_envs.envs.tasks import place, state
from embodied_envs.envs.tasks.scene import TaskReader, support_heights
from embodied_envs.layout.assets import asset_geometry

UPRIGHT = ROOT / "tests" / "data" / "upright"
TILT = np.deg2rad(30)  # a mover leaning on the receptacle's outer wall


def resting_height(parts, xy: np.ndarray, points: np.ndarray, default: float) -> float:
    """The height, in the receptacle's frame (its convex ``parts``), of a mover's centre at
    ``xy`` standing as it is (``points (V, 3)``: its collision points about its centre) on the
    receptacle: the lowest at which none of its points is under the surface straight below it
    (a can near a bowl's curved wall stands on the ring of its base that meets the wall; on
    the rim, on the rim). ``default``: the surface's height where no part is under any point."""
    heights = support_heights(parts, xy + points[:, :2], -np.inf) - points[:, 2]
    best = heights.max()
    return float(best) if np.isfinite(best) else default - float(points[:, 2].min())


class Scene:
    """One env of an upright layout, reset, with the receptacle's geometry to pose its movers."""

    def __init__(self, name: str):
        self.env = gym.make("PickEmbodiedGen-v1", layout_file=str(UPRIGHT / f"{name}.json"),
                            obs_mode="state", control_mode="pd_joint_pos")  # fmt: skip
        self.env.reset(seed=0)
        u = self.u = self.env.unwrapped
        ts, layout = u.task_scene, u.layouts[0]
        self.rec = asset_geometry(layout.asset_spec(ts.tasks[0].receptacle))
        pose = ts.receptacle.pose.raw_pose[0].numpy().astype(np.float64)
        self.rec_p = pose[:3]
        self.rec_rot = sapien.Pose(q=pose[3:]).to_transformation_matrix()[:3, :3]
        self.points = ts.hulls[0] - ts.centres[0][:, None]  # movers' points about their centres
        self.table_z = float(u.layout_scene.top_z[0])
        self.rim_xy = np.abs(self.rec.footprint()).max(0)  # the footprint's half sizes

    def centre_on(self, k: int, xy, up: float = 0.0) -> np.ndarray:
        """Mover ``k``'s centre, upright, resting at ``xy`` in the receptacle's frame (on its
        floor, its rim, wherever its points meet the surface), ``up`` higher; world frame."""
        pts = self.points[k] @ self.rec_rot  # upright in the world: in the receptacle's frame
        z = resting_height(self.rec.parts, np.asarray(xy, float), pts, self.rec.max_z)
        return self.rec_p + self.rec_rot @ np.array([*xy, z]) + [0, 0, up]

    def put(self, k: int, centre, q=(1.0, 0.0, 0.0, 0.0)) -> None:
        """Mover ``k`` with its centre at ``centre`` (world), turned ``q``, still."""
        ts = self.u.task_scene
        rot = sapien.Pose(q=list(q)).to_transformation_matrix()[:3, :3]
        origin = np.asarray(centre) - rot @ ts.centres[0, k]
        actor = ts.movers[k]
        actor.set_pose(Pose.create_from_pq(torch.tensor(origin[None], dtype=torch.float32),
                                           torch.tensor([q], dtype=torch.float32)))  # fmt: skip
        actor.set_linear_velocity(torch.zeros(1, 3))
        actor.set_angular_velocity(torch.zeros(1, 3))

    def leaning(self, k: int) -> tuple[np.ndarray, tuple]:
        """Mover ``k``'s centre and turn tilted ``TILT`` towards the receptacle, its lowest
        point on the table just outside the receptacle's footprint (along the receptacle's x
        axis)."""
        foot = self.rec_p + self.rec_rot @ [self.rim_xy[0] + 0.005, 0, 0]
        towards = self.rec_p - foot
        towards[2] = 0.0
        towards /= np.linalg.norm(towards)
        axis = np.cross([0.0, 0.0, 1.0], towards)  # turning about it tips the top towards it
        q = (np.cos(TILT / 2), *(np.sin(TILT / 2) * axis))
        rot = sapien.Pose(q=list(q)).to_transformation_matrix()[:3, :3]
        pts = self.points[k] @ rot.T
        low = pts[pts[:, 2].argmin()]
        return np.array([*(foot - low)[:2], self.table_z - low[2]]), q

    def grade(self) -> tuple[bool, list[str]]:
        """Success and the unmet conditions, read as the CPU reads them (numpy) and as the GPU
        does (tensors through ManiSkill's structs), which agree."""
        u, arrays = self.u, self.u.task_reader
        graded = bool(u.evaluate()["success"][0]), arrays.unmet()[0]
        u.task_reader = TaskReader(u, u.task_scene, u.layout_scene.top_z, tensors=True)
        u.task_reader.dest = torch.as_tensor(arrays.dest)
        try:
            assert (bool(u.evaluate()["success"][0]), u.task_reader.unmet()[0]) == graded
        finally:
            u.task_reader = arrays
        return graded


@pytest.fixture(scope="module")
def scenes():
    made = {}
    yield lambda name: made.setdefault(name, Scene(name))
    for s in made.values():
        s.env.close()


SINGLE = ["can_in_bowl", "bottle_in_bowl", "can_in_small_bowl", "can_in_tray", "bottle_in_tray",
          "can_in_shallow_bowl"]  # fmt: skip


@pytest.mark.parametrize("name", SINGLE)
def test_an_upright_mover_on_the_floor_is_in_however_tall(name, scenes):
    s = scenes(name)
    s.put(0, s.centre_on(0, (0.0, 0.0)))
    centre_z = s.u.task_reader.state(s.u.task_reader.goal()).in_receptacle[0, 0, 2]
    assert centre_z > s.rec.max_z  # its centre above the rim: the old rule's "not in"
    assert s.grade() == (True, [])


@pytest.mark.parametrize("name", SINGLE)
def test_on_the_rim_leaning_held_above_or_beside_is_not_in(name, scenes):
    s = scenes(name)
    node = s.u.tasks[0].objects[0]
    # standing on the rim: its centre over the footprint 1 cm inside its edge
    s.put(0, s.centre_on(0, (s.rim_xy[0] - 0.01, 0.0)))
    assert s.grade() == (False, [f"{node}: not resting on its floor"])
    # leaning on the outer wall from the table
    s.put(0, *s.leaning(0))
    ok, why = s.grade()
    assert not ok and len(why) == 1 and "touching the table" in why[0], why
    # held (still) 5 cm above its place on the floor: nothing under it
    s.put(0, s.centre_on(0, (0.0, 0.0), up=s.rec.max_z - s.rec.min_z + 0.05))
    assert s.grade() == (False, [f"{node}: not resting on its floor"])
    # beside it on the table
    beside = s.rec_p + s.rec_rot @ [s.rim_xy[0] + 0.08, 0, 0]
    s.put(0, [*beside[:2], s.table_z - s.points[0][:, 2].min()])
    assert s.grade() == (False, [f"{node}: not over the receptacle, touching the table"])


@pytest.mark.parametrize("name", ["cans_in_bowl", "cans_in_tray"])
def test_two_cans_in_it_and_a_can_standing_on_another(name, scenes):
    s = scenes(name)
    s.put(0, s.centre_on(0, (-0.035, 0.0)))
    s.put(1, s.centre_on(1, (0.035, 0.0)))
    assert s.grade() == (True, [])
    # can2 standing on can1, which stands on the floor: in, resting on a mover in it
    first = s.centre_on(0, (0.0, 0.0))
    s.put(0, first)
    height = np.ptp(s.points[0][:, 2])
    s.put(1, first + [0, 0, height + 0.001])
    assert s.grade() == (True, [])
    # can1 on the rim, can2 on it: neither is in
    first = s.centre_on(0, (s.rim_xy[0] - 0.01, 0.0))
    s.put(0, first)
    s.put(1, first + [0, 0, height + 0.001])
    ok, why = s.grade()
    assert not ok and why == ["can1: not resting on its floor", "can2: not resting on its floor"]


# --- the rule on set states (numpy and torch alike) ----------------------------------------
def two_movers(bottoms, heights, xs, is_in=True):
    """Two 6 cm wide movers over a 0.2 m square receptacle whose frame is at z 0, its floor at
    0, its rim 0.02 m: lowest points ``bottoms``, heights ``heights``, centres at ``xs``."""
    from embodied_envs.layout.placement.rules import half_planes

    square = np.array([[-0.1, -0.1], [0.1, -0.1], [0.1, 0.1], [-0.1, 0.1]])
    normals, offsets = half_planes(square)
    b, h = np.array([bottoms], float), np.array([heights], float)
    centres = np.stack([np.array([xs], float), np.zeros((1, 2)), b + h / 2], -1)
    return state.TaskState(
        tcp=np.array([[0.0, 0.0, 0.5]]), goal=np.zeros((1, 3)), arm_speed=np.zeros((1, 7)),
        opening=np.array([1.0]), movers=centres, origins=centres, lin_vel=np.zeros((1, 2, 3)),
        ang_vel=np.zeros((1, 2, 3)), bottom=b, grasped=np.zeros((1, 2), bool),
        start=centres + [0.3, 0, 0], dest=centres, in_receptacle=centres,
        footprint=(normals[None], offsets[None]), rim=np.array([0.02]), floor=np.array([0.0]),
        rec_top=np.array([0.02]), rec_pos=np.zeros((1, 3)), is_in=np.array([is_in]),
        rec_is_table=np.array([False]), table_z=np.array([-0.01]),
        direction=np.array([[0.0, 1.0]]), top=b + h,
        reach=np.full((1, 2), np.hypot(0.03, max(heights) / 2)),
    )  # fmt: skip


@pytest.mark.parametrize(
    "case, bottoms, heights, xs, success",
    [
        ("two tall movers on the floor", (0.0, 0.0), (0.2, 0.12), (-0.04, 0.04), True),
        ("the second on the first's top", (0.0, 0.12), (0.12, 0.12), (0.0, 0.0), True),
        ("the second lying across the first", (0.0, 0.1), (0.1, 0.03), (0.0, 0.03), True),
        ("the first on the rim, the second on it", (0.02, 0.14), (0.12, 0.12), (0.09, 0.09),
         False),
        ("the second beside the first, over the rim's height", (0.0, 0.05), (0.12, 0.12),
         (0.0, 0.09), False),
        ("the second 2 cm over the first's top", (0.0, 0.14), (0.12, 0.12), (0.0, 0.0), False),
    ],
)  # fmt: skip
def test_a_mover_resting_on_another_in_it_is_in(case, bottoms, heights, xs, success):
    s = two_movers(bottoms, heights, xs)
    for t in (s, as_torch(s)):
        assert bool(place.evaluate(t)["success"][0]) is success, case


def as_torch(s: state.TaskState) -> state.TaskState:
    def to(v):
        if v is None:
            return v
        return tuple(torch.as_tensor(x) for x in v) if isinstance(v, tuple) else torch.as_tensor(v)

    return state.TaskState(**{k: to(v) for k, v in vars(s).items()})


def test_on_likewise_a_mover_on_one_on_the_top_is_on_it():
    """"On": the second standing on the first, which stands on the top (2 cm rim), is on it;
    the second 2 cm over the first's top is not."""
    on = two_movers((0.02, 0.14), (0.12, 0.12), (0.0, 0.0), is_in=False)
    hovering = two_movers((0.02, 0.16), (0.12, 0.12), (0.0, 0.0), is_in=False)
    for s, success in ((on, True), (hovering, False)):
        for t in (s, as_torch(s)):
            assert bool(place.evaluate(t)["success"][0]) is success


def test_a_receptacle_without_an_inside_holds_nothing_in_it():
    """A floor less than ``MIN_DEPTH`` under the top (a lid, a slab): never "in"; "on" it."""
    s = two_movers((0.02, 0.02), (0.1, 0.1), (-0.04, 0.04))
    lid = state.TaskState(**{**vars(s), "floor": np.array([0.02 - place.MIN_DEPTH / 2])})
    assert not place.evaluate(lid)["success"][0]
    on = state.TaskState(**{**vars(lid), "is_in": np.array([False])})
    assert place.evaluate(on)["success"][0]


def test_support_heights_follow_a_curved_floor():
    """``support_heights`` (the floor the rule measures depth from; the poses above): a can
    off the centre of the zoo's shallow bowl, on its sloped wall, no point under the surface,
    one on it."""
    from embodied_envs.layout.assets import parse_urdf

    bowl = asset_geometry(parse_urdf(ROOT / "tests/data/zoo/assets/shallow_bowl/shallow_bowl.urdf"))
    ring = np.array([[0.03 * np.cos(a), 0.03 * np.sin(a), -0.06]
                     for a in np.linspace(0, 2 * np.pi, 32, endpoint=False)])  # fmt: skip
    for x in (0.0, 0.03):
        z = resting_height(bowl.parts, np.array([x, 0.0]), ring, bowl.max_z)
        surface = support_heights(bowl.parts, ring[:, :2] + [x, 0.0], -np.inf)
        gaps = z + ring[:, 2] - surface
        assert gaps.min() == pytest.approx(0.0, abs=1e-9), x
    centre = resting_height(bowl.parts, np.zeros(2), ring, bowl.max_z)
    assert centre == pytest.approx(0.008 + 0.06, abs=1e-6)  # its flat floor, 8 mm up
    assert resting_height(bowl.parts, np.array([0.03, 0.0]), ring, bowl.max_z) > centre + 0.01


def test_an_episode_that_fails_says_which_condition(scenes):
    """``run_episode`` (demo, collect, eval): the can never moved is reported beside the bowl."""
    from embodied_envs.pipelines.episodes import run_episode

    s = scenes("can_in_small_bowl")
    episode = run_episode(s.env, 0, drive=lambda tally, obs, seed: [])
    assert not episode.success and episode.steps == 0
    assert episode.unmet == ["can: not over the receptacle, touching the table"]
    assert episode.failure == "execution (can: not over the receptacle, touching the table)"


def test_the_failure_reason_names_the_conditions():
    from embodied_envs.pipelines.episodes import Episode

    ep = Episode(layout="x", seed=0, success=False, fail=False, steps=3, episode_return=0.0,
                 unmet=["can: not released", "can2: not at rest"])  # fmt: skip
    assert ep.failure == "execution (can: not released; can2: not at rest)"
    ep.plan_failures = ["carry: no plan"]
    assert ep.failure == "carry (can: not released; can2: not at rest)"


@pytest.mark.parametrize("name, seed", [("can_in_small_bowl", 0), ("bottle_in_tray", 1)])
def test_the_expert_stands_a_tall_mover_in_it(name, seed):
    """The expert's place ends in the pose the rule calls "in" (before: 0 of 10 seeds of every
    upright layout, the movers in place and graded "execution"; docs/tasks.md "The expert")."""
    from embodied_envs.solvers.pick_place import PickPlaceSolver

    env = gym.make("PickEmbodiedGen-v1", layout_file=str(UPRIGHT / f"{name}.json"),
                   obs_mode="state", control_mode="pd_joint_pos")  # fmt: skip
    try:
        env.reset(seed=seed)
        result = PickPlaceSolver(env, seed=seed).solve()
        u = env.unwrapped
        assert result.success.all(), u.task_reader.unmet()
        centre = u.task_reader.state(u.task_reader.goal()).in_receptacle[0, 0, 2]
        assert centre > u.task_scene.rim[0]  # standing, its centre above the rim
    finally:
        env.close()
