"""PickEmbodiedGen-v1: pick the layout's target object and hold it at a goal."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
import sapien
import torch
from gymnasium.utils import seeding
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building import actors
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs.pose import Pose
from mani_skill.utils.structs.types import GPUMemoryConfig, SceneConfig, SimConfig
from mani_skill.utils.visualization.misc import tile_images

from embodied_envs.envs.arguments import (
    check_action,
    check_env_idx,
    check_num_envs,
    check_seed,
    dataclass_arg,
    fields_of,
)
from embodied_envs.envs.config import SUPPORTED_ROBOTS, CameraSpec, resolve_robot
from embodied_envs.envs.hybrid import HybridRenderer, stacked_ids
from embodied_envs.layout import LayoutInfo, load_layout
from embodied_envs.layout.placement import PlacementLimits, derive_seed, place
from embodied_envs.paths import default_layout
from embodied_envs.scene import GoalRegion, LayoutScene, load_layout_scene

PICK_EMBODIEDGEN_DOC = """**Task Description:**
Pick up the layout's target object (the first of ``relation.manipulated_objs``) with the
Panda, which stands on the table's edge as the layout places it, and hold it still at a goal
point above the table (a green sphere in human renders, hidden from sensors). Distractors and
the table are obstacles. The scene comes from an EmbodiedGen layout file.

**Randomizations:**
- per configuration (construction, ``reconfiguration_freq``, ``reset(options=dict(reconfigure=
  True))``), with ``replace_objs=True``: table yaw, robot spot and background yaw are re-drawn
  per env by the seeded BFS placement, except env 0 on the first configuration, which keeps
  the file's poses. Splat backgrounds are rendered then and cached.
- per episode (every ``reset``, only the reset envs), with ``replace_objs=True``: every object on
  the table is re-drawn on its env's table with the placement constraints (footprint inside the
  shrunk top, no overlap, robot base clear, manipulated objects within reach and heading)
- ``replace_objs=False``: the file's poses, always
- arm joints: rest pose plus N(0, ``robot_init_qpos_noise``); fingers open at 0.04
- goal: uniform over the region above the table top within the robot's reach
  (``goal_region``), 0.05 to 0.25 m above the top

**Success Conditions:**
- the object is within ``goal_thresh`` (0.025 m) of the goal, and
- the robot is static (arm joint speeds below 0.2 rad/s)

**Action Space:** the Panda controller's (default ``pd_joint_delta_pos``).

**Observation Space:** ManiSkill's agent state plus ``extra``: ``tcp_pose``, ``goal_pos``,
``is_grasped``; in state modes also ``obj_pose``, ``tcp_to_obj_pos``, ``obj_to_goal_pos``.
Visual modes add the 128x128 ``base_camera`` (composited over the splat with ``hybrid_obs``).

**Rewards:** see ``compute_dense_reward``; the normalised dense reward is in [0, 1].

**Episode End:** truncation after ``MAX_EPISODE_STEPS`` = 300 control steps (6 s, registry):
the scripted expert needs ~140 and at most ~245; ``success`` is reported in ``info``.

**Arguments:** ``layout_file``, ``replace_objs``, ``robot_uids`` (default: from the layout's
robot name), ``robot_init_qpos_noise``, ``init_3dgs_quat``, ``objs_z_offset``,
``robot_z_offset``, ``camera_cfg``, ``enable_grasp`` (accepted, unused),
``hybrid_obs`` (sensor RGB composited over the splat, whatever ``render_mode`` is; recorded in
``env_kwargs``, so replays reproduce it), ``hybrid_depth_test`` (hide simulated pixels behind
the splat surface), ``splat_backend`` (``"auto"``, ``"torch"`` or ``"gsplat"``),
``placement_limits`` and ``goal_region`` (dicts of :class:`PlacementLimits` /
:class:`GoalRegion` fields),
plus ManiSkill's own (``num_envs``, ``obs_mode``, ``control_mode``, ``render_mode``, ...).
"""

REST_QPOS = np.array(
    [0.0, np.pi / 8, 0.0, -3 * np.pi / 8, 0.0, 3 * np.pi / 4, np.pi / 4, 0.04, 0.04]
)


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


# 300 control steps = 6 s at 50 Hz: the scripted expert's longest successful episode over 50
# seeded episodes per shipped layout was 245 steps (mean ~140; tools/bench_solver.py), so every
# demonstration fits, and a policy gets the expert's horizon with ~20% slack
MAX_EPISODE_STEPS = 300


@register_env("PickEmbodiedGen-v1", max_episode_steps=MAX_EPISODE_STEPS)
class PickEmbodiedGenEnv(BaseEnv):
    __doc__ = PICK_EMBODIEDGEN_DOC

    SUPPORTED_ROBOTS = SUPPORTED_ROBOTS
    SUPPORTED_RENDER_MODES = ("human", "rgb_array", "sensors", "all", "hybrid")
    metadata = {"render_modes": SUPPORTED_RENDER_MODES}

    goal_thresh = 0.025  # m, object-to-goal distance that counts as placed
    static_thresh = 0.2  # rad/s, arm joint speed under which the robot is static
    max_reward = 5.0  # dense reward on success; the normalised reward divides by it
    base_camera_eye = (0.95, 0.0, 0.55)  # base_camera eye in the robot base frame, m
    base_camera_target = (0.30, 0.0, 0.0)  # base_camera target in the robot base frame, m

    def __init__(
        self,
        *args,
        layout_file: str | os.PathLike | None = None,
        replace_objs: bool = True,
        robot_uids: str | None = None,
        robot_init_qpos_noise: float = 0.02,
        init_3dgs_quat: tuple[float, float, float, float] = (0.7071, 0.0, 0.0, 0.7071),
        objs_z_offset: float = 0.002,
        robot_z_offset: float = 0.002,
        camera_cfg: dict | None = None,
        enable_grasp: bool = False,  # EmbodiedGen's keyword: accepted, has no effect
        hybrid_obs: bool = False,
        hybrid_depth_test: bool = True,
        splat_backend: str = "auto",
        placement_limits: dict | PlacementLimits | None = None,
        goal_region: dict | GoalRegion | None = None,
        num_envs: int = 1,
        render_mode: str | None = None,
        **kwargs,
    ):
        # everything the user gave is checked before any simulation object exists
        if render_mode is not None and render_mode not in self.SUPPORTED_RENDER_MODES:
            raise ValueError(
                f"render_mode={render_mode!r} is not supported; use one of "
                f"{list(self.SUPPORTED_RENDER_MODES)} or None"
            )
        check_num_envs(num_envs, kwargs.get("sim_backend", "auto"))
        self.camera_spec = CameraSpec.from_cfg(camera_cfg)
        self.layout_file = Path(layout_file) if layout_file is not None else default_layout()
        self.base_layout: LayoutInfo = load_layout(self.layout_file)
        robot = resolve_robot(self.base_layout.robot, robot_uids, str(self.layout_file))
        self.placement_limits = dataclass_arg(PlacementLimits, placement_limits, "placement_limits")
        self.goal_region = dataclass_arg(GoalRegion, goal_region, "goal_region")
        self.replace_objs = bool(replace_objs)
        if self.replace_objs:  # an impossible layout fails here, not mid-simulation
            place(self.base_layout, 0, **fields_of(self.placement_limits))
        self.robot_init_qpos_noise = float(robot_init_qpos_noise)
        self.init_3dgs_quat = tuple(float(v) for v in init_3dgs_quat)
        self.objs_z_offset = float(objs_z_offset)
        self.robot_z_offset = float(robot_z_offset)
        self.hybrid_depth_test = bool(hybrid_depth_test)
        self.hybrid_obs = bool(hybrid_obs)
        self.hybrid: HybridRenderer | None = None
        self._backgrounds_due = False  # set at (re)configuration, cleared by the pre-render
        if render_mode == "hybrid" or self.hybrid_obs:
            self.hybrid = HybridRenderer(
                self.base_layout.gs_model_path(),
                self.init_3dgs_quat,
                depth_test=self.hybrid_depth_test,
                backend=splat_backend,
                layout_file=self.layout_file,
            )  # on the CPU until the simulation's device is known (at configuration)
        self._num_configurations = 0
        self.layouts: list[LayoutInfo] = [self.base_layout] * num_envs
        self.env_actors: dict[str, dict[str, Any]] = {}
        super().__init__(
            *args,
            robot_uids=robot,
            num_envs=num_envs,
            render_mode=render_mode,
            **kwargs,
        )

    @property
    def spec(self):
        return self.__dict__.get("_spec")

    @spec.setter
    def spec(self, spec) -> None:
        # gymnasium sets the spec that RecordEpisode stores as env_kwargs: keep the layout file
        # absolute there, so a recorded dataset re-creates the env from any working directory
        layout = None if spec is None else spec.kwargs.get("layout_file")
        if layout is not None:
            absolute = str(Path(layout).resolve())
            spec = dataclasses.replace(spec, kwargs={**spec.kwargs, "layout_file": absolute})
        self.__dict__["_spec"] = spec

    # --- configuration -------------------------------------------------------------------
    @property
    def _default_sim_config(self):
        return SimConfig(
            sim_freq=100,
            control_freq=50,
            scene_config=SceneConfig(solver_position_iterations=30),
            gpu_memory_config=GPUMemoryConfig(
                max_rigid_contact_count=2**20, max_rigid_patch_count=2**19
            ),
        )

    @property
    def _default_sensor_configs(self):
        pose = sapien_utils.look_at(eye=self.base_camera_eye, target=self.base_camera_target)
        mount = self.agent.robot.links_map[self.agent.robot.links[0].name]
        return [CameraConfig("base_camera", pose, 128, 128, np.pi / 2, 0.01, 100, mount=mount)]

    @property
    def _default_human_render_camera_configs(self):
        cam = self.camera_spec
        pose = sapien_utils.look_at(eye=cam.eye, target=cam.target)
        return CameraConfig(
            "render_camera", pose, cam.width, cam.height, np.deg2rad(cam.fovy_deg), 0.01, 100
        )

    def _layouts_for_configuration(self) -> list[LayoutInfo]:
        """Env 0 keeps the file's poses on the first configuration; otherwise re-place."""
        first = self._num_configurations == 0
        self._num_configurations += 1
        if not self.replace_objs:
            return [self.base_layout] * self.num_envs
        seeds = np.asarray(self._episode_seed).reshape(-1)
        return [
            self.base_layout
            if (first and k == 0)
            else place(
                self.base_layout, derive_seed(seeds[k], k), **fields_of(self.placement_limits)
            )
            for k in range(self.num_envs)
        ]

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=[0.0, 0.0, 0.0]))

    def _load_scene(self, options: dict):
        self.layouts = self._layouts_for_configuration()
        self.layout_scene: LayoutScene = load_layout_scene(
            self.scene,
            self.layouts,
            objs_z_offset=self.objs_z_offset,
            robot_z_offset=self.robot_z_offset,
            limits=self.placement_limits,
            goal_region=self.goal_region,
            device=self.device,
        )
        self.env_actors = self.layout_scene.env_actors
        # each node is one state entry over all envs (its per-env actors live in one sub-scene)
        for env in self.env_actors.values():
            for actor in env.values():
                self.remove_from_state_dict_registry(actor)
        for node in self.layout_scene.dynamic_nodes:
            self.add_to_state_dict_registry(self.layout_scene.node_actors[node])
        self.obj = self.layout_scene.target
        self.goal_site = actors.build_sphere(
            self.scene,
            radius=self.goal_thresh,
            color=[0, 1, 0, 1],
            name="goal_site",
            body_type="kinematic",
            add_collision=False,
            initial_pose=sapien.Pose(),
        )
        self._hidden_objects.append(self.goal_site)

    def _reconfigure(self, options: dict | None = None):
        options = {} if options is None else options
        if self.render_mode == "human" and not _has_display():
            # headless: no viewer window; "human" then returns the render camera's frames
            self.render_mode = "rgb_array"
            try:
                super()._reconfigure(options)
            finally:
                self.render_mode = "human"
        else:
            super()._reconfigure(options)

    # --- episodes ------------------------------------------------------------------------
    def reset(self, seed: int | list[int] | None = None, options: dict | None = None):
        self._check_open("reset")
        check_seed(seed, self.num_envs)
        options = check_env_idx(options, self.num_envs, self.device)
        if seed is not None:
            # gymnasium's own generator follows the reset seed too, as gymnasium's checker and
            # wrappers expect (ManiSkill only seeds its episode RNGs); nothing here draws from it
            first = np.asarray(seed).reshape(-1)[0]
            self._np_random, self._np_random_seed = seeding.np_random(int(first))
        result = super().reset(seed=seed, options=options)
        if self.hybrid is not None and self._backgrounds_due:
            self.hybrid.prerender(self.scene)  # at (re)configuration, not at the first frame
            self._backgrounds_due = False
        return result

    def step(self, action):
        self._check_open("step")
        action = check_action(
            action, tuple(self.single_action_space.shape), self.num_envs, self.control_mode
        )
        if isinstance(action, torch.Tensor):
            action = action.to(self.device)
        return super().step(action)

    def close(self):
        self._closed = True
        super().close()

    def _check_open(self, call: str) -> None:
        if self.__dict__.get("_closed"):
            raise RuntimeError(f"{call}() on a closed PickEmbodiedGen-v1 env; make a new env")

    def _set_episode_rng(self, seed, env_idx: torch.Tensor):
        super()._set_episode_rng(seed, env_idx)
        if getattr(self, "layout_scene", None) is not None:
            if seed is not None:  # ManiSkill re-created every env's episode RNG
                self.layout_scene.episodes.invalidate()
            elif self._enhanced_determinism:  # ... or those of env_idx
                self.layout_scene.episodes.invalidate(torch.as_tensor(env_idx, device=self.device))

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        b = len(env_idx)
        ls = self.layout_scene
        start = ls.episodes.draw(env_idx, self._batched_episode_rng)
        with torch.device(self.device):
            self.agent.robot.set_root_pose(Pose.create(ls.robot_poses[env_idx]))
            qpos = torch.as_tensor(REST_QPOS, dtype=torch.float32).repeat(b, 1)
            qpos[:, :-2] += self.robot_init_qpos_noise * start.joint_noise  # fingers stay 0.04
            self.agent.reset(qpos)
            zeros = torch.zeros((b, 3))
            for node in ls.dynamic_nodes:
                if self.replace_objs and node in start.objects:
                    pose = start.objects[node]
                else:  # the configuration's pose: replace_objs=False, or a floor object
                    pose = ls.node_poses[node][env_idx]
                actor = ls.node_actors[node]
                actor.set_pose(Pose.create(pose))
                actor.set_linear_velocity(zeros)
                actor.set_angular_velocity(zeros)
            self.goal_site.set_pose(Pose.create_from_pq(start.goal))

    # --- task ----------------------------------------------------------------------------
    def evaluate(self):
        obj_to_goal_pos = self.goal_site.pose.p - self.obj.pose.p
        is_obj_placed = torch.linalg.norm(obj_to_goal_pos, axis=1) <= self.goal_thresh
        is_robot_static = self.agent.is_static(self.static_thresh)
        return {
            "success": is_obj_placed & is_robot_static,
            "is_obj_placed": is_obj_placed,
            "is_robot_static": is_robot_static,
            "is_grasped": self.agent.is_grasping(self.obj),
            "obj_to_goal_pos": obj_to_goal_pos,
        }

    def _get_obs_extra(self, info: dict):
        obs = dict(
            is_grasped=info["is_grasped"],
            tcp_pose=self.agent.tcp_pose.raw_pose,
            goal_pos=self.goal_site.pose.p,
        )
        if "state" in self.obs_mode:
            obs.update(
                obj_pose=self.obj.pose.raw_pose,
                tcp_to_obj_pos=self.obj.pose.p - self.agent.tcp_pose.p,
                obj_to_goal_pos=self.goal_site.pose.p - self.obj.pose.p,
            )
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """Staged dense reward, in [0, 5].

        - reaching, [0, 1]: ``1 - tanh(5 * |tcp - obj|)``
        - grasped, {0, 1}
        - placing, [0, 1] while grasped: ``1 - tanh(5 * |obj - goal|)``
        - static, [0, 1] while placed: ``1 - tanh(5 * |arm qvel|)``
        - success: the maximum, 5
        """
        tcp_to_obj = torch.linalg.norm(self.obj.pose.p - self.agent.tcp_pose.p, axis=1)
        reward = 1 - torch.tanh(5 * tcp_to_obj)
        is_grasped = info["is_grasped"].float()
        reward = reward + is_grasped
        obj_to_goal = torch.linalg.norm(info["obj_to_goal_pos"], axis=1)
        reward = reward + (1 - torch.tanh(5 * obj_to_goal)) * is_grasped
        qvel = self.agent.robot.get_qvel()[..., :-2]
        static = 1 - torch.tanh(5 * torch.linalg.norm(qvel, axis=1))
        reward = reward + static * info["is_obj_placed"].float()
        reward[info["success"]] = self.max_reward
        return reward

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs=obs, action=action, info=info) / self.max_reward

    # --- rendering -----------------------------------------------------------------------
    def _after_reconfigure(self, options: dict):
        super()._after_reconfigure(options)
        if self.hybrid is not None:
            ls = self.layout_scene
            self.hybrid.to(self.device).configure(
                foreground_ids=stacked_ids(self.agent.robot.links + list(ls.node_actors.values())),
                hidden_ids=stacked_ids(self._hidden_objects),
                background_poses=[x.pose(self.base_layout.background) for x in self.layouts],
            )
            self._backgrounds_due = True

    def get_sensor_params(self) -> dict[str, dict[str, torch.Tensor]]:
        # new tensors on every call: SAPIEN returns its cached intrinsic matrix, and an
        # observation must not change when a later one is taken
        return {
            name: {k: v.clone() for k, v in params.items()}
            for name, params in super().get_sensor_params().items()
        }

    def _get_obs_sensor_data(self, apply_texture_transforms: bool = True) -> dict:
        obs = super()._get_obs_sensor_data(apply_texture_transforms)
        if self.hybrid_obs and apply_texture_transforms:  # a policy sees what a person sees
            self.hybrid.composite_sensors(self.scene, obs)
        return obs

    def render_hybrid(self) -> torch.Tensor:
        """The human render cameras' images composited over the splat background."""
        images = self.hybrid.render(self.scene, self._hidden_objects)
        return images[0] if len(images) == 1 else tile_images(images)

    def render(self):
        if self.render_mode == "hybrid":
            return self.render_hybrid()
        return super().render()

    def render_human(self):
        if _has_display():
            super().render_human()
        return self.render_rgb_array()
