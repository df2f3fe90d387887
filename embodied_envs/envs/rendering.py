"""The env's cameras and its hybrid-render plumbing.

:func:`base_camera` (:func:`robot_camera`: at the robot entry's eye and target) and
:func:`render_camera` build the sensor and the human render camera's configs.
:class:`HybridRendering` is a mixin for a :class:`~embodied_envs.envs.base.CheckedEnv` that loads
a layout scene (``self.layouts``, ``self.layout_scene``): it holds ``render_mode="hybrid"`` and
``hybrid_obs``. ``HybridRenderer`` (``envs/hybrid.py``) does the compositing; the mixin only
hands it the simulator's images at the points ManiSkill makes them.
"""

from __future__ import annotations

import numpy as np
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils

from embodied_envs.config import CameraSpec
from embodied_envs.envs.hybrid import HybridRenderer, stacked_ids
from embodied_envs.internals import link_components
from embodied_envs.layout.rooms import ROOM_FILE, RoomError, draw_rooms, resolve_rooms
from embodied_envs.scene.visual_detail import simplify_visuals


def base_camera(agent, eye, target, mount: str) -> CameraConfig:
    """The 128x128 ``base_camera`` sensor, mounted on the robot's link ``mount`` (its robot
    entry's ``camera_mount``); ``eye`` and ``target`` in that link's frame (m)."""
    pose = sapien_utils.look_at(eye=eye, target=target)
    mount = agent.robot.links_map[mount]
    return CameraConfig("base_camera", pose, 128, 128, np.pi / 2, 0.01, 100, mount=mount)


def robot_camera(agent, entry, layout_scene) -> CameraConfig:
    """The ``base_camera`` of the robot entry ``entry`` (its ``camera_eye``, ``camera_target``
    and ``camera_mount``), given at the layout's robot spot: a base that stands on the floor
    (``base_height == "floor"``) sits lower by env 0's spot height over the floor."""
    drop = 0.0
    if entry.base_height == "floor":  # the base stands on the floor under env 0's spot
        drop = float(layout_scene.robot_poses[0, 2]) - float(layout_scene.floor_z)
    eye, target = (entry.in_base_frame(p, drop) for p in (entry.camera_eye, entry.camera_target))
    return base_camera(agent, eye, target, entry.camera_mount)


def render_camera(spec: CameraSpec, framing: tuple | None) -> CameraConfig:
    """The human ``render_camera``: ``spec``'s eye and target, or ``framing``'s (eye, target)
    when given."""
    eye, target = framing if framing is not None else (spec.eye, spec.target)
    pose = sapien_utils.look_at(eye=eye, target=target)
    fovy = np.deg2rad(spec.fovy_deg)
    return CameraConfig("render_camera", pose, spec.width, spec.height, fovy, 0.01, 100)


class HybridRendering:
    """``render_mode="hybrid"`` (``render()`` composites the human render cameras over the
    splat) and ``hybrid_obs`` (sensor observations composited likewise), for an env with
    ``layouts`` and ``layout_scene``. Set up by :meth:`_set_up_hybrid` before
    ``BaseEnv.__init__``."""

    hybrid: HybridRenderer | None = None
    room_pool: list | None = None  # the splats each episode draws its room from (``rooms``)
    robot_visual_faces: int | None = None  # the robot's visual mesh parts decimated to this

    def _set_up_hybrid(
        self, render_mode, hybrid_obs, depth_test, backend, init_3dgs_quat, layouts,
        rooms=None, robot_visual_faces=None,
    ) -> str | None:  # fmt: skip
        """Sets ``hybrid_obs``, ``render_hybrid``, ``room_pool``, ``robot_visual_faces`` and
        ``hybrid`` (the renderer, or None when neither is asked for); returns the render mode
        to give ManiSkill: a hybrid env is an ``rgb_array`` env to every wrapper, and its
        ``render()`` composites.

        Raises:
            RoomError: ``rooms`` names no room, or it is given without hybrid rendering.
        """
        self.hybrid_obs = bool(hybrid_obs)
        self.render_hybrid = render_mode == "hybrid"
        self.robot_visual_faces = robot_visual_faces
        pool = resolve_rooms(rooms)
        self.room_pool = None if pool is None else [room / ROOM_FILE for room in pool]
        self.hybrid = None
        if self.room_pool is not None and not (self.render_hybrid or self.hybrid_obs):
            raise RoomError(
                f"rooms={rooms!r}: rooms are splat backgrounds and nothing is composited over "
                'them. Fix: hybrid_obs=True (collect/eval --hybrid-obs) or render_mode="hybrid"'
            )
        if self.render_hybrid or self.hybrid_obs:  # moves to the sim's device when known
            rooms_used = {x.gs_model_path(): x.source for x in reversed(layouts)}
            rooms_used |= {path: f"rooms={rooms!r}" for path in self.room_pool or []}
            self.hybrid = HybridRenderer(
                rooms_used,
                tuple(float(v) for v in init_3dgs_quat),
                depth_test=bool(depth_test),
                backend=backend,
            )
        return "rgb_array" if self.render_hybrid else render_mode

    def _load_agent(self, options: dict, *args, **kwargs):
        super()._load_agent(options, *args, **kwargs)
        if self.robot_visual_faces is not None:  # what every camera sees of the robot
            for agent in getattr(self.agent, "agents", [self.agent]):
                entities = [c.entity for link in agent.robot.links for c in link_components(link)]
                simplify_visuals(entities, self.robot_visual_faces)

    def _after_reconfigure(self, options: dict):
        super()._after_reconfigure(options)
        if self.hybrid is not None:
            self.hybrid.to(self.device).configure(
                foreground_ids=stacked_ids(
                    [link for a in getattr(self.agent, "agents", [self.agent])
                     for link in a.robot.links]
                    + list(self.layout_scene.node_actors.values())
                ),
                hidden_ids=stacked_ids(self._hidden_objects),
                background_poses=[x.pose(x.background) for x in self.layouts],
                rooms=[x.gs_model_path() for x in self.layouts],
            )

    def draw_rooms(self, env_idx) -> None:
        """With a room pool, each env of ``env_idx`` draws its episode's room (uniform, from
        its episode RNG: seeded resets give the same rooms); without one, nothing."""
        if self.room_pool is None or self.hybrid is None:
            return
        envs = [int(e) for e in np.asarray(env_idx.cpu() if hasattr(env_idx, "cpu") else env_idx)]
        picks = draw_rooms(self._batched_episode_rng[envs], len(self.room_pool))
        self.hybrid.set_rooms(envs, [self.room_pool[k] for k in picks])

    def reset(self, seed: int | list[int] | None = None, options: dict | None = None):
        result = super().reset(seed=seed, options=options)
        if self.hybrid is not None and self.render_hybrid:  # render()'s backgrounds, now
            self.hybrid.prerender(self.scene)  # after a (re)configuration: the new backgrounds
        return result

    def _get_obs_sensor_data(self, apply_texture_transforms: bool = True) -> dict:
        obs = super()._get_obs_sensor_data(apply_texture_transforms)
        # a policy sees what a person sees: colour, depth, points and segmentation agree
        if self.hybrid_obs and apply_texture_transforms:
            self.hybrid.composite_sensors(self.scene, obs)
        return obs

    def get_obs(self, info: dict | None = None, unflattened: bool = False):
        obs = super().get_obs(info, unflattened)
        if self.hybrid_obs and self.obs_mode == "pointcloud":  # splat points at their place
            self.hybrid.place_splat_points(obs["pointcloud"], obs["sensor_param"])
        return obs

    def render_rgb_array(self, camera_name: str | None = None):
        if self.render_hybrid:
            return self.hybrid.render(self.scene, self._hidden_objects, camera_name)
        return super().render_rgb_array(camera_name)

    def render_simulated(self, camera_name: str | None = None):
        """The human render cameras' plain simulator images, without the splat."""
        return super().render_rgb_array(camera_name)
