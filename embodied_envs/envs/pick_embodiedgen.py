"""PickEmbodiedGen-v1: a robot at a table does an EmbodiedGen layout's task (pick, place, move)."""

from __future__ import annotations

import contextlib
import os
from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.agents.robots.fetch.fetch import FETCH_WHEELS_COLLISION_BIT
from mani_skill.utils.building import actors
from mani_skill.utils.building.ground import build_ground
from mani_skill.utils.registration import register
from mani_skill.utils.structs.pose import Pose
from mani_skill.utils.structs.types import GPUMemoryConfig, SceneConfig, SimConfig

from embodied_envs.config import SPLAT_Y_UP_TO_Z_UP, SUPPORTED_ROBOTS, CameraSpec
from embodied_envs.envs import agents, fast_control, fast_reads, keywords, physx_scene
from embodied_envs.envs.arguments import check_quaternion
from embodied_envs.envs.base import CheckedEnv
from embodied_envs.envs.graspable import check_graspable
from embodied_envs.envs.observation import StateObservation, check_movers
from embodied_envs.envs.rendering import HybridRendering, render_camera, robot_camera
from embodied_envs.envs.tasks import INFO_KEYS, KIND_IDS, RULES, pick
from embodied_envs.envs.tasks.scene import TaskReader, TaskScene, as_tensor
from embodied_envs.envs.tasks.state import concat, some
from embodied_envs.layout import GoalRegion, LayoutInfo, PlacementLimits
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.paths import default_layout
from embodied_envs.registration import CONTROL_FREQ, ENV_ID, MAX_EPISODE_STEPS
from embodied_envs.scene import load_layout_scene
from embodied_envs.scene.layout_scene import configuration_layouts


class PickEmbodiedGenEnv(HybridRendering, CheckedEnv):
    """**Task Description:**
    The robot (``robot_uids``, else the layout's ``relation.robot``; or two arms, the second
    across the table) stands at the table's edge where an EmbodiedGen layout file places it and
    does the layout's task (``env.unwrapped.tasks``; docs/tasks.md): ``pick`` the target object
    (the first of ``relation.manipulated_objs``) and hold it still at a goal point above the
    table (a green sphere in human renders, hidden from sensors), ``place`` movers in or on a
    receptacle, or ``move`` a mover 10 cm or more along a direction. Distractors and the table
    are obstacles; a ground at the layout's floor level catches a knocked-off object.

    **Randomizations** (docs/layouts.md, "Placement"; ``replace_objs=False``: the file's poses):
    - per configuration: each env's layout and pooled assets from a layout set
      (``env.unwrapped.layouts``), then its table yaw, robot spot and background yaw
    - per episode (the reset envs): every object on the table, within the placement limits;
      the goal within the robot's reach (``goal_region``); the arm joints,
      ``robot_init_qpos`` plus N(0, ``robot_init_qpos_noise``); with ``rooms``, the splat room

    **Success Conditions:** by the env's task kind, ``envs/tasks/<kind>.py``. **Fail
    Conditions:** a mover, or a receptacle object, off the table: more than ``fail_drop`` below
    the table's top, or its origin outside the top's footprint (docs/layouts.md, "The floor").

    **Observation Space:** ManiSkill's agent state plus ``extra``: ``is_grasped``, ``tcp_pose``,
    ``goal_pos`` (the pick goal, or the first mover's destination), ``task_kind`` (one-hot);
    state modes add every mover and the receptacle in fixed, masked slots, one shape over any
    layout set (``envs/observation.py``; docs/tasks.md, "Observations"); visual modes the
    ``base_camera`` (128x128; ``sensor_configs``). **Action Space:** the robot controller's (default
    ``pd_joint_delta_pos``). **Rewards:** :meth:`compute_dense_reward`; normalised to [0, 1].
    **Episode End:** ``terminated`` on ``success`` or ``fail``; truncated after
    ``MAX_EPISODE_STEPS`` (500) control steps, 10 s.

    **Arguments:** ``__init__``'s keywords (README.md, "Keywords"; checked in
    ``envs/keywords.py``), ManiSkill's own, ``config`` files (``embodied_envs/config.py``);
    ``render_mode="hybrid"`` composites frames over the splat (docs/hybrid_rendering.md).
    """

    SUPPORTED_ROBOTS = SUPPORTED_ROBOTS
    SUPPORTED_RENDER_MODES = (*CheckedEnv.SUPPORTED_RENDER_MODES, "hybrid")
    metadata = {"render_modes": SUPPORTED_RENDER_MODES}

    fail_drop = 0.05  # m, the object this far below the table's top has fallen off
    # the framed render camera (camera_cfg without an eye or target): past the table's centre,
    # away from the robot, looking back at the robot over the table
    render_camera_back = 0.9  # m from the table's centre, away from the robot
    render_camera_rise = (0.34, 0.14)  # m above the table's top: the eye, the target
    number_ranges = keywords.NUMBER_RANGES  # numeric keywords: (low, high)

    @classmethod
    def check_keyword(cls, name: str, value) -> None:
        """A keyword's type (``CheckedEnv``) and range, checked as ``__init__`` checks it."""
        super().check_keyword(name, value)
        keywords.check_value(name, value)

    def __init__(
        self,
        *args,
        # a layout file, a folder, a glob, or a list of these (a set: each env draws one per
        # configuration); default: the shipped default layout
        layout_file: str | os.PathLike | list | None = None,
        replace_objs: bool = True,
        robot_uids: str | list | tuple | None = None,  # one uid, or two (two arms)
        robot_init_qpos_noise: float = 0.02,
        # the rest joints (arm + gripper) instead of the robot entry's; two arms: the first's
        robot_init_qpos: list[float] | tuple[float, ...] | None = None,
        init_3dgs_quat: tuple[float, float, float, float] = SPLAT_Y_UP_TO_Z_UP,
        objs_z_offset: float = 0.002,
        robot_z_offset: float = 0.002,
        camera_cfg: dict | None = None,  # camera_eye, camera_target_pt, image_hw, fovy_deg
        enable_grasp: bool = False,  # EmbodiedGen's keyword: accepted, has no effect
        hybrid_obs: bool = False,  # sensor RGB over the splat, whatever render_mode is
        hybrid_depth_test: bool = True,  # simulated pixels behind the splat surface are hidden
        splat_backend: str = "auto",  # or "torch", "gsplat"
        rooms: str | os.PathLike | list | None = None,  # a room pool: each episode draws one
        robot_visual_faces: int | None = None,  # the robot's visual mesh parts decimated to this
        placement_limits: dict | PlacementLimits | None = None,
        goal_region: dict | GoalRegion | None = None,
        render_mode: str | None = None,
        **kwargs,
    ):
        self.camera_spec = CameraSpec.from_cfg(camera_cfg)  # all checked before any simulation
        # no eye or target given: the render camera is framed on the robot and the table
        self.frame_render_camera = not {"camera_eye", "camera_target_pt"} & set(camera_cfg or {})
        self.layout_set = LayoutSet.load(default_layout() if layout_file is None else layout_file)
        files = self.layout_set.files  # absolute
        self.layout_file = files[0] if len(files) == 1 else files
        self.base_layout: LayoutInfo = self.layout_set.layouts[0]
        robot, self.robot_entries = keywords.robot_arms(self.layout_set, robot_uids)
        self.robot_entry = self.robot_entries[0]  # the arm the task's TCP and grasp follow
        check_graspable(self.layout_set, self.robot_entry)  # an object its jaws cannot take
        check_movers(self.layout_set.layouts)  # more movers than the observation's slots
        if len(self.robot_entries) > 1:  # ManiSkill's multi-agent env (warns if not listed)
            self.SUPPORTED_ROBOTS = [*SUPPORTED_ROBOTS, robot]
        # each arm's rest joints (robot_init_qpos: its length now, its limits once loaded)
        self.robot_rests = keywords.rest_joints(robot_init_qpos, self.robot_entries)
        self.robot_init_qpos = None if robot_init_qpos is None else self.robot_rests[0].tolist()
        # reach and goals follow the robot, for each field the user did not set
        self.placement_limits, self.goal_region = keywords.limits_and_goals(
            self.robot_entry, placement_limits, goal_region, self.robot_init_qpos
        )
        for name, value in dict(
            robot_init_qpos_noise=robot_init_qpos_noise, objs_z_offset=objs_z_offset,
            robot_z_offset=robot_z_offset, replace_objs=replace_objs, enable_grasp=enable_grasp,
            hybrid_obs=hybrid_obs, hybrid_depth_test=hybrid_depth_test,
            init_3dgs_quat=init_3dgs_quat, robot_visual_faces=robot_visual_faces, rooms=rooms,
        ).items():  # fmt: skip
            self.check_keyword(name, value)  # as a config file's values are checked
        init_3dgs_quat = check_quaternion("init_3dgs_quat", init_3dgs_quat)
        self.replace_objs = bool(replace_objs)
        keywords.check_layout_set(
            self.layout_set, self.replace_objs, self.placement_limits, kwargs.get("num_envs", 1)
        )
        self.robot_init_qpos_noise = float(robot_init_qpos_noise)
        self.objs_z_offset, self.robot_z_offset = float(objs_z_offset), float(robot_z_offset)
        render_mode = self._set_up_hybrid(  # a hybrid env is an rgb_array env to ManiSkill
            render_mode, hybrid_obs, hybrid_depth_test, splat_backend, init_3dgs_quat,
            self.layout_set.layouts, rooms, robot_visual_faces,
        )  # fmt: skip
        self._num_configurations = 0
        super().__init__(*args, robot_uids=robot, render_mode=render_mode, **kwargs)

    @property
    def _default_sim_config(self):
        gpu_memory = GPUMemoryConfig(max_rigid_contact_count=2**20, max_rigid_patch_count=2**19)
        return SimConfig(
            sim_freq=2 * CONTROL_FREQ, control_freq=CONTROL_FREQ, gpu_memory_config=gpu_memory,
            scene_config=SceneConfig(solver_position_iterations=30),
        )  # fmt: skip

    @property
    def _default_sensor_configs(self):
        return [robot_camera(self.main_agent, self.robot_entry, self.layout_scene)]

    @property
    def _default_human_render_camera_configs(self):
        framing = None  # on this configuration's robot and table (env 0's)
        if self.frame_render_camera:
            framing = self.layout_scene.framing(self.render_camera_back, *self.render_camera_rise)
        return render_camera(self.camera_spec, framing)

    def _load_agent(self, options: dict):
        placed = [sapien.Pose(p=[0.0, 0.0, 0.0]) for _ in self.robot_entries]  # per episode
        super()._load_agent(options, placed if len(placed) > 1 else placed[0])
        if self.robot_init_qpos is not None:  # before anything is simulated
            keywords.check_rest_limits(self.robot_rests[0], self.main_agent, self.robot_entry.uid)
        for agent, entry in zip(agents.all_agents(self), self.robot_entries, strict=True):
            agents.set_pads(agent, entry)  # and ManiSkill's set_action in numpy (CPU only):
            fast_control.install(agent)

    @property
    def main_agent(self):
        """The arm the task's TCP, grasp check and expert follow: the one robot, or the first
        of two (``env.agent.agents[0]``)."""
        return agents.all_agents(self)[0]

    def _load_scene(self, options: dict):
        self._num_configurations += 1
        self.layouts = configuration_layouts(
            self.layout_set, self._episode_seed, self.placement_limits,
            first=self._num_configurations == 1, replace=self.replace_objs,
        )  # fmt: skip
        ls = self.layout_scene = load_layout_scene(
            self.scene, self.layouts, self.objs_z_offset, self.robot_z_offset,
            self.placement_limits, self.goal_region, self.device,
        )  # fmt: skip
        self.env_actors, self.obj = ls.env_actors, ls.target_actor
        self.instructions = [layout.instruction for layout in self.layouts]  # one per env
        span = tuple(float(np.float32(q)) for q in self.robot_entry.gripper.span)  # as PhysX
        spots = ls.robot_poses.cpu().numpy()
        self.task_scene = TaskScene.build(self.layouts, ls.env_actors, spots, span)
        self.tasks = self.task_scene.tasks  # one per env (layout/task.py)
        self.task_reader = TaskReader(self, self.task_scene, ls.top_z)
        self.state_observation = StateObservation(self.task_scene, self.task_reader, self.device)
        # each arm's spot (the layout's; a second arm's across the table) and base pose
        self.robot_spots, self.robot_bases = agents.arm_bases(
            self.robot_entries, spots, ls.episodes.top_arrays, self.placement_limits.hull_margin,
            float(ls.floor_z), ls.robot_poses.device,
        )  # fmt: skip
        ls.register_state(self)
        self.ground = build_ground(self.scene, altitude=ls.floor_z)
        if self.robot_entry.mobile_base:  # its wheels clear the ground (ManiSkill's table scene)
            self.ground.set_collision_group_bit(group=2, bit_idx=FETCH_WHEELS_COLLISION_BIT, bit=1)
        self.goal_site = actors.build_sphere(
            self.scene, radius=pick.GOAL_THRESH, color=[0, 1, 0, 1], name="goal_site",
            body_type="kinematic", add_collision=False, initial_pose=sapien.Pose(),
        )  # fmt: skip
        self._hidden_objects.append(self.goal_site)

    def _set_episode_rng(self, seed, env_idx: torch.Tensor):
        super()._set_episode_rng(seed, env_idx)  # new RNGs: drop starts drawn from the old ones
        if getattr(self, "layout_scene", None) is not None:
            self.layout_scene.episodes.reseeded(seed, env_idx, self._enhanced_determinism)

    def _clear_sim_state(self):
        physx_scene.before_reset(self)  # CPU: a new PhysX scene, whatever ran before
        super()._clear_sim_state()

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        ls = self.layout_scene
        start = ls.episodes.draw(env_idx, self._batched_episode_rng)
        # no device mode on the CPU (its hook on every torch call: 1-2 ms of a reset)
        with torch.device(self.device) if self.gpu_sim_enabled else contextlib.nullcontext():
            agents.reset_arms(
                agents.all_agents(self), self.robot_entries, self.robot_bases, self.robot_rests,
                env_idx, self.robot_init_qpos_noise, start.joint_noise,
            )  # fmt: skip
            ls.set_episode_poses(env_idx, start.objects if self.replace_objs else {})
            dest = self.task_reader.begin_episode(env_idx, start.goal)
            # the goal marker: the pick goal, or where the first mover goes
            is_pick = (self.task_scene.kinds == KIND_IDS["pick"]).to(self.device)[env_idx]
            goal = torch.where(is_pick[:, None], torch.as_tensor(start.goal), dest[:, 0])
            self.goal_site.set_pose(Pose.create_from_pq(goal))
        if not self.gpu_sim_enabled:  # bodies settle as in a new scene, whatever ran before
            fast_reads.restart_sleep_timers(self.scene)
        self.draw_rooms(env_idx)  # after the episode's placement draws: they stay as they were

    def task_rules(self):
        """The task state now and each present kind's rule results (``envs/tasks``)."""
        return self.task_reader.rules(self.task_reader.goal())

    def evaluate(self):
        state, results = self.task_rules()
        self._last_rules = (state, results)
        info = {key: self.task_reader.by_kind(results, key) for key in ("success", *INFO_KEYS)}
        # a mover off the table, or the receptacle knocked off: one check for all
        points = concat([state.movers, state.rec_pos[:, None]], 1)
        off = self.layout_scene.off_table(points, self.fail_drop) & self.task_reader.can_fall
        info["fail"] = as_tensor(some(off, 1), self.device)
        return info

    def _before_control_step(self):
        self.task_reader.before_step()  # the arm's speeds: its displacement over each step

    def set_state_dict(self, state: dict, env_idx=None):
        super().set_state_dict(state, env_idx)  # set before a first step: where movers start
        self.task_reader.state_set(env_idx, self.goal_site.pose.p)  # (--use-first-env-state)

    def get_state_dict(self):
        """ManiSkill's, read in one pass on the CPU simulation (``envs/fast_reads.py``)."""
        return super().get_state_dict() if self.gpu_sim_enabled else fast_reads.cpu_state_dict(self)

    def _get_obs_extra(self, info: dict):
        tcp = agents.tcp_pose(self.main_agent, self.robot_entry)  # once: 0.3 ms for some arms
        obs = dict(
            is_grasped=info["is_grasped"],
            tcp_pose=tcp.raw_pose,
            goal_pos=self.goal_site.pose.p,
            task_kind=torch.nn.functional.one_hot(self.task_scene.kinds, len(RULES)).to(
                self.device, torch.float32),  # pick, place, move  # fmt: skip
        )
        if "state" in self.obs_mode:  # every mover and the receptacle, in fixed slots
            obs.update(self.state_observation.extras(tcp.p))
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """Each env's kind's staged dense reward (``envs/tasks/<kind>.py`` ``reward``), from
        0 to that kind's ``MAX_REWARD`` (reached on success only)."""
        state, results = self._last_rules if hasattr(self, "_last_rules") else self.task_rules()
        rewards = {k: {"reward": RULES[k].reward(state, res)} for k, res in results.items()}
        return self.task_reader.by_kind(rewards, "reward").float()

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs, action, info) / self.task_reader.max_reward


register(ENV_ID, PickEmbodiedGenEnv, max_episode_steps=MAX_EPISODE_STEPS)
