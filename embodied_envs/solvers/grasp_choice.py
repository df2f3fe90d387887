"""The expert's grasp choice: which grasps to try where the target lies now, best first.

The top-down grasp across the footprint's narrow side (``grasp_frame``; a round body's widest
section) and its turns, the asset's annotated grasps (``affordance_annot.json``) and the
synthesised grasps the gripper can take here (``solvers/grasps.py``), in the order the solver
tries them. ``GraspChoice`` is a mixin of
:class:`~embodied_envs.solvers.pick_place.PickPlaceSolver`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import sapien

from embodied_envs.layout.assets import (
    ASSET_FILES,
    AssetSpec,
    FileVersion,
    asset_geometry,
    convex_hull_2d,
    parse_urdf,
)
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.solvers.grasp_types import GraspConfig
from embodied_envs.solvers.grasps import (
    GraspError,
    asset_grasps,
    grasp_is_valid,
    object_points,
    posed_clearance,
    posed_grasps,
    widest_height,
)
from embodied_envs.solvers.planar import lowest_centre, off_reach, planar_grasps, table_gap
from embodied_envs.solvers.solver_config import SolverConfig

# rad: ``SolverConfig.fixed_hand`` takes a synthesised grasp this close to straight down and to
# the hand's closing direction
FIXED_SLACK = np.deg2rad(15.0)


def asset_spec(layout, node: str) -> AssetSpec:
    """``layout.asset_spec(node)``, its URDF read once per file version (``ASSET_FILES``): the
    solver asks for every object's at every episode (a millisecond each, parsed)."""
    urdf = layout.urdf_path(node)
    return ASSET_FILES.get(("asset spec", FileVersion.of(urdf)), lambda: parse_urdf(urdf))


def grasp_pose(approach: np.ndarray, closing: np.ndarray, centre: np.ndarray) -> sapien.Pose:
    """The grasp frame's pose: z along ``approach``, y along ``closing`` (unit, orthogonal),
    its origin at ``centre``."""
    rot = np.stack([np.cross(closing, approach), closing, approach], axis=1)
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rot, centre
    return sapien.Pose(m)


def grasp_frame(
    vertices_world: np.ndarray, support_z: float, cfg: SolverConfig, current_y: np.ndarray
):
    """Grasp centre and closing direction for a top-down grasp.

    The closing direction is the narrow side of the minimum-area rectangle around the object's
    XY footprint; its sign is the one closest to the gripper's current closing axis. Its height
    is ``grasp_depth`` below the top, or a round body's widest section
    (``grasps.widest_height``), not under ``min_tcp_height`` above the support.
    """
    hull = convex_hull_2d(vertices_world[:, :2])
    best = None
    for i in range(len(hull)):
        e = hull[(i + 1) % len(hull)] - hull[i]
        u = e / (np.linalg.norm(e) + 1e-12)
        v = np.array([-u[1], u[0]])
        pu, pv = hull @ u, hull @ v
        area = (pu.max() - pu.min()) * (pv.max() - pv.min())
        if best is None or area < best[0]:
            best = (area, u, v, pu, pv)
    _, u, v, pu, pv = best
    wu, wv = pu.max() - pu.min(), pv.max() - pv.min()
    closing2 = u if wu < wv else v
    centre2 = u * (pu.max() + pu.min()) / 2 + v * (pv.max() + pv.min()) / 2
    closing = np.array([closing2[0], closing2[1], 0.0])
    if np.dot(closing, current_y) < 0:
        closing = -closing
    top = vertices_world[:, 2].max()
    lowest = support_z + cfg.min_tcp_height
    z = min(max(top - cfg.grasp_depth, lowest), top - 0.005)
    z = widest_height(vertices_world, closing, z, top - 0.005, lowest)  # a round body: its equator
    return np.array([centre2[0], centre2[1], z]), closing


def _held_so(grasps, object_to_world: np.ndarray, hand_y: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: the grasps a hand kept at its orientation takes (``SolverConfig.fixed_hand``):
    within ``FIXED_SLACK`` of straight down, closing within it of ``hand_y`` either way."""
    rot = object_to_world[:3, :3]
    cos = np.cos(FIXED_SLACK)
    down = -(grasps.approach @ rot.T)[:, 2] >= cos
    return down & (np.abs(grasps.closing @ rot.T @ hand_y) >= cos)


# the part of the friction cone of the jaws' pads against an object that a grasp found on
# tilted rays may use (``GraspConfig.tilted_cone_deg``): pads of friction 2 (the SO-100's, the
# Koch's) on a block (0.6) give 35 degrees; ManiSkill's Koch pads (0.3) gave 16
TILTED_SHARE = 2 / 3


class GraspChoice:
    """The grasps to try per env (a mixin of the solver)."""

    def asset_config(self, spec) -> GraspConfig:
        """The grasp synthesis' numbers for an asset (``spec``): ``tilted_cone_deg``,
        ``TILTED_SHARE`` of the friction cone of the jaws' pads on it (PhysX averages the
        two materials' friction: the robot's pads, ``Robot.pads``, and the asset's mu2); none
        where the robot names no pad material."""
        pads = self.base.robot_entry.pads(self.base.main_agent.urdf_config)
        if pads is None:
            return self.grasp_config
        mu = (pads + spec.dynamic_friction) / 2
        cone = TILTED_SHARE * np.degrees(np.arctan(mu))
        return dataclasses.replace(self.grasp_config, tilted_cone_deg=float(cone))

    def grasp_poses(self) -> list[list[tuple[sapien.Pose, float]]]:
        """Per env, the grasps to try where its target lies now, best first, each with the
        finger opening to approach with. First the top-down grasp across the footprint's
        narrow side and its 180-degree turn (a parallel gripper's same grasp at another wrist
        angle), fully open, when it passes the synthesised grasps' checks and clears the
        other objects by the wide margin (the grasp that cans and boxes take); then the
        synthesised grasps the gripper can take here (``grasps.posed_grasps``, pre-shaped);
        the footprint grasp last when it failed those checks, or when the asset's annotated
        grasps (``affordance_annot.json``) lead the synthesised ones."""
        tcp = self._tcp().to_transformation_matrix().cpu().numpy()
        gripper = self.gripper_model
        poses = []
        # per env a label per grasp, the same for one grasp at other wrist turns (a planar
        # hand's: ``_planar``), or None: ``ArmDriver._choose``'s ``twins``
        self.grasp_twins: list[list[int] | None] = [None] * self.num_envs
        for i, layout in enumerate(self.base.layouts):
            actor = self.base.env_actors[f"env{i}"][self._node(i)]
            spec = asset_spec(layout, self._node(i))
            geom = asset_geometry(spec)
            pose = LayoutPose.from_raw(actor.pose.raw_pose[0].cpu().numpy())
            support = float(self.base.layout_scene.top_z[i])
            try:
                grasps = asset_grasps(spec, self.asset_config(spec), gripper)
            except GraspError as e:  # this hand takes the object nowhere: said per episode
                if not self.reports[i].plan_failures:
                    self.reports[i].plan_failures.append(f"grasp: {e}")
                poses.append([])
                continue
            hand_y = np.array([*tcp[i, :2, 1], 0.0]) / max(np.linalg.norm(tcp[i, :2, 1]), 1e-9)
            keep = _held_so(grasps, pose.matrix(), hand_y) if self.cfg.fixed_hand else None
            # a planar hand poses the asset's contact pairs its own way (``_planar``)
            planar = self.robot_hand.planar and not self.cfg.fixed_hand
            taken = [] if planar else posed_grasps(
                grasps, pose.matrix(), support, self.clouds[i], self.grasp_config, gripper,
                limit=self.cfg.grasp_candidates, with_index=True, keep=keep,
                roomy_first=not self.cfg.consistent,
            )  # fmt: skip
            # with a fixed hand or a consistent expert, closing along the hand's (the jaws'
            # symmetry): the same grasp at the wrist angle nearest the hand's
            fold = self.cfg.fixed_hand or self.cfg.consistent
            synthesised = [
                (grasp_pose(approach, closing * np.sign(closing @ hand_y or 1.0), centre), opening)
                if fold else (grasp_pose(approach, closing, centre), opening)
                for centre, closing, approach, opening, _ in taken
            ]  # fmt: skip
            # the asset's own annotated grasps (affordance_annot.json) lead when one is takeable
            annotated = bool(taken) and grasps.annotated is not None
            annotated = annotated and bool(grasps.annotated[taken[0][4]])
            verts = pose.transform_points(geom.vertices)
            centre, closing = grasp_frame(verts, support, self.cfg, tcp[i, :3, 1])
            checked = (i, grasps, pose, centre)
            if self.cfg.fixed_hand:
                fits = self._footprint_fits(*checked, hand_y, support)
                down = np.array([0, 0, -1.0])
                poses.append([(grasp_pose(down, hand_y, centre), gripper.opening)] * fits
                             + synthesised)  # fmt: skip
                continue
            if planar:
                options, labels = self._planar(checked, closing, support, gripper)
                if not options:  # none in the arm's plane: the pairs on tilted rays too
                    also = dataclasses.replace(self.asset_config(spec), tilted_too=True)
                    checked = (i, asset_grasps(spec, also, gripper), pose, centre)
                    options, labels = self._planar(checked, closing, support, gripper)
                points = pose.transform_points(object_points(spec, self.cfg.obstacle_points))
                poses.append(self._against_fixed_jaw(options, points))
                # the two ways are one grasp where a still jaw's shift places the object
                # against it either way (the SO-100's, the Koch's)
                self.grasp_twins[i] = labels if self.robot_hand.fixed_jaw else None
                continue
            down = np.array([0, 0, -1.0])
            footprint = [
                (grasp_pose(down, c, centre), gripper.opening)
                for c in (closing, -closing)
            ]
            turned = self._turned_closing(i, tcp[i], centre)
            if turned is not None and self._footprint_fits(*checked, turned, support):
                # the wrist needs no turn: first
                footprint.insert(0, (grasp_pose(down, turned, centre),
                                     gripper.opening))  # fmt: skip
            first = self._footprint_fits(*checked, closing, support) and not annotated
            poses.append(footprint + synthesised if first else synthesised + footprint)
        return poses

    def _planar(self, checked, closing, support, gripper) -> tuple[list, list[int]]:
        """A planar hand's grasps (``robots.Hand.planar``): of the footprint's centre, the
        approach in the arm's vertical plane, tilted ``planar_tilts`` from straight down
        toward the far side, closing along the footprint's narrow side as far as that is
        across the approach (either way: the wrist roll takes one or the other), the centre
        raised where the tilted fingers would reach into the table (a short object), each kept
        when it passes the footprint grasp's checks; then the synthesised grasps posed with
        the approach the arm can make for each contact pair (``solvers/planar.py``). And a
        label per grasp, the same for one grasp's two ways (a two-jaw grasp turned by pi: the
        wrist roll either way, within its range), of which the solver takes the one its arm
        reaches soonest (``ArmDriver._choose``'s ``twins``)."""
        i, grasps, pose, centre = checked
        base = self.base.agent.robot.pose.raw_pose[i, :2].cpu().numpy()  # tilt_reach's origin
        axis = self._pan_axis()[i]
        out = centre[:2] - axis
        out = np.array([*(out / max(np.linalg.norm(out), 1e-9)), 0.0])
        across = np.array([-out[1], out[0], 0.0])  # the plane's normal
        top = float(pose.transform_points(asset_geometry(asset_spec(
            self.base.layouts[i], self._node(i))).vertices)[:, 2].max())  # fmt: skip
        # the table's own surface points are obstacles too: its top is the height check's
        cloud = self.clouds[i]
        cloud = cloud[cloud[:, 2] > support + table_gap(self.grasp_config)]
        reach = self.robot_hand.tilts_at(float(np.linalg.norm(centre[:2] - base)))
        tilts = sorted(self.cfg.planar_tilts,
                       key=lambda t: float(off_reach(np.deg2rad(t), reach)))  # fmt: skip

        def approach_at(tilt):  # tilted from straight down toward the far side, in the plane
            return np.cos(tilt) * np.array([0, 0, -1.0]) + np.sin(tilt) * out

        # the footprint's closing turned square to the approach leans off the narrow side by
        # asin(|closing . approach|): the jaws then meet a box's faces at their edges and push
        # it; the least lean first among the reachable tilts, none past the friction cone
        lean = lambda t: abs(closing @ approach_at(np.deg2rad(t)))  # noqa: E731
        cone = np.sin(np.deg2rad(self.grasp_config.cone_deg))
        footprint_tilts = sorted((t for t in tilts if lean(t) <= cone), key=lambda t: (
            float(off_reach(np.deg2rad(t), reach)), round(lean(t), 2)))  # fmt: skip
        poses, labels = [], []
        for label, tilt in enumerate(np.deg2rad(footprint_tilts)):
            approach = approach_at(tilt)
            c = closing - (closing @ approach) * approach
            c = c / np.linalg.norm(c) if np.linalg.norm(c) > 1e-6 else across
            for way in (c, -c):
                low = lowest_centre(gripper, way[None], approach[None], gripper.opening)[0]
                at = centre.copy()
                at[2] = max(at[2], support + table_gap(self.grasp_config) + low)
                if at[2] < top and self._footprint_fits(i, grasps, pose, at, way, support,
                                                        approach, cloud):  # fmt: skip
                    poses.append((grasp_pose(approach, way, at), gripper.opening))
                    labels.append(label)
        planar = planar_grasps(
            grasps, pose.matrix(), axis, support, cloud, tuple(tilts),
            lambda xy: self.robot_hand.tilts_at(np.linalg.norm(xy - base, axis=1)),
            self.grasp_config, gripper, self.cfg.grasp_candidates,
        )  # fmt: skip
        # planar_grasps gives its grasps, then each again the other way
        first = len(footprint_tilts)
        labels += [first + k % max(len(planar) // 2, 1) for k in range(len(planar))]
        return poses + [(grasp_pose(a, c, p), o) for p, c, a, o in planar], labels

    def _against_fixed_jaw(self, poses: list, verts: np.ndarray) -> list:
        """``poses`` of a hand with a jaw that stands still (``robots.Hand.fixed_jaw``) moved
        along their closing line so that the object (``verts``, world: its vertices and surface
        points, ``grasps.object_points``) lies the arm's precision (``GraspConfig.margin``) from
        that jaw's inner face, the other jaw ``preshape`` past the object's far side (at most
        its widest, ``Hand.action_openings``' last: opened wide, the Koch's jaw took 3 s to
        close in its delta modes): it then presses the object that far onto the still jaw, not
        across the gap between the open jaws (the SO-100's still jaw stands 3.85 cm from the
        grasp origin: a 2 cm marker centred there lay 2.9 cm from it, and was pushed 1.4-2 cm
        and missed). The object's extent is its points between the jaws
        (``GripperModel.between``): an L-shaped block's other leg, out past the fingers' side,
        had put the still jaw 2.9 cm from the bar it closed on. The checks the grasp passed
        were the hand model's, about the unmoved centre. Unchanged without one."""
        face = self.robot_hand.fixed_jaw
        if not face:
            return poses
        way = np.sign(face)
        wide_open = self.robot_hand.action_openings[-1][0]  # the widest gap the jaw holds
        out = []
        for pose, _ in poses:
            m = pose.to_transformation_matrix()
            local = (verts - m[:3, 3]) @ m[:3, :3]  # the grasp frame
            between = self.gripper_model.between(local)
            y, cfg = local[between, 1], self.grasp_config
            shift = (way * y).max() + cfg.margin - abs(face)
            gap = min(wide_open, cfg.margin + np.ptp(y) + cfg.preshape)
            out.append((sapien.Pose(m[:3, 3] + shift * way * m[:3, 1], pose.q), gap))
        return out

    def _footprint_fits(
        self, i, grasps, pose, centre, closing, support, down: np.ndarray | None = None,
        cloud: np.ndarray | None = None,
    ) -> bool:  # fmt: skip
        """Whether env i's grasp at ``centre`` closing along ``closing``, approaching along
        ``down`` (straight down unless given), passes the synthesised grasps' checks on the
        object (``pose``) and clears the other objects (``cloud``: env i's obstacle points
        unless given) by the wide margin."""
        down = np.array([0, 0, -1.0]) if down is None else down
        world_to_object = np.linalg.inv(pose.matrix())
        rot, t = world_to_object[:3, :3], world_to_object[:3, 3]
        # the footprint grasp's palm stops just above a can's lid: checked without margin
        exact = dataclasses.replace(self.grasp_config, margin=0.0)
        valid = grasp_is_valid(
            grasps, rot @ centre + t, rot @ closing, rot @ down, exact, self.gripper_model
        )
        _, roomy = posed_clearance(
            centre[None], closing[None], down[None],
            self.gripper_model.boxes(self.grasp_config.sweep)[None], support,
            self.clouds[i] if cloud is None else cloud, self.grasp_config,
        )  # fmt: skip
        return valid and bool(roomy[0])

    def _turned_closing(self, i: int, tcp: np.ndarray, centre: np.ndarray) -> np.ndarray | None:
        """The hand's closing direction now (``tcp (4, 4)``) turned about the vertical as the
        arm's base joint turns from the hand to ``centre``: the top-down grasp there the wrist
        reaches without turning (a can's footprint has no narrow side, and a turn of the last
        joint by up to 90 degrees took 2 s at the convertible speeds); None where the hand's
        closing direction is vertical."""
        base = self._pan_axis()[i]
        y = tcp[:2, 1]
        if np.linalg.norm(y) < 0.5:
            return None
        a, b = centre[:2] - base, tcp[:2, 3] - base
        turn = np.arctan2(a[1], a[0]) - np.arctan2(b[1], b[0])
        c, s = np.cos(turn), np.sin(turn)
        xy = np.array([c * y[0] - s * y[1], s * y[0] + c * y[1]])
        return np.array([*(xy / np.linalg.norm(xy)), 0.0])
