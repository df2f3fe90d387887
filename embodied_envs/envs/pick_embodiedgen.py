"""PickEmbodiedGen-v1: pick the layout's target object and hold it at a goal."""

from __future__ import annotations

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

from embodied_envs import robots
from embodied_envs.config import SPLAT_Y_UP_TO_Z_UP, SUPPORTED_ROBOTS, CameraSpec
from embodied_envs.envs import agents, fast_reads, keywords
from embodied_envs.envs.arguments import check_quaternion, dataclass_arg
from embodied_envs.envs.base import CheckedEnv
from embodied_envs.envs.rendering import HybridRendering, base_camera, render_camera
from embodied_envs.envs.tasks import INFO_KEYS, KIND_IDS, RULES, pick
from embodied_envs.envs.tasks.scene import TaskReader, TaskScene
from embodied_envs.layout import GoalRegion, LayoutInfo, PlacementLimits
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.paths import default_layout
from embodied_envs.registration import CONTROL_FREQ, ENV_ID, MAX_EPISODE_STEPS
from embodied_envs.scene import load_layout_scene
from embodied_envs.scene.layout_scene import configuration_layouts


class PickEmbodiedGenEnv(HybridRendering, CheckedEnv):
    """**Task Description:**
    Pick up the layout's target object (the first of ``relation.manipulated_objs``) with the
    robot (``robot_uids``, else the layout's ``relation.robot``; ``embodied_envs/robots.py``),
    which stands at the table's edge as the layout places it, and hold it still at a goal
    point above the table (a green sphere in human renders, hidden from sensors). Distractors
    and the table are obstacles. The scene comes from an EmbodiedGen layout file. A static
    ground lies at the layout's floor level (the lowest point of its ``FLOOR`` objects; z = 0
    when none): a knocked-off object comes to rest there. In hybrid frames the splat's room
    floor shows instead of it.

    **Randomizations** (``replace_objs=False``: the file's poses, always):
    - per configuration (construction, ``reconfiguration_freq``, ``reconfigure=True``): with a
      layout set (``layout_file`` a list, folder or glob) or asset pools, each env's layout and
      pooled assets (``layout.sets.LayoutSet.draw``, from the env's seed); then table
      yaw, robot spot and background yaw per env, by the seeded placement (env 0 keeps the
      file's poses on the first configuration, unless the set has pools); splat backgrounds
      are rendered then. ``env.unwrapped.layouts`` holds each env's layout,
      ``env.unwrapped.instructions`` its task in words
    - per episode (the reset envs): every object on the table, within the placement limits
    - arm joints: the robot entry's ``rest_qpos`` plus N(0, ``robot_init_qpos_noise``) on its
      ``noise_joints``; fingers open
    - goal: uniform over the table top within the robot's reach (``goal_region``)

    **Task** (per env, ``env.unwrapped.tasks``; ``layout/task.py`` reads it from the layout:
    ``relation.task``, else the sentence ``relation.task_desc``): ``pick`` (hold the object at
    the goal), ``place`` (movers in or on a receptacle) or ``move`` (a mover 10 cm or more along
    a direction). Success, fail extras and the dense reward of each kind: ``envs/tasks/``.

    **Fail Conditions:** ``fail`` when a mover, or a receptacle object, is off the table: more
    than ``fail_drop`` (0.05 m) below the table's top, or its origin outside the top's footprint.

    **Action Space:** the robot controller's (default ``pd_joint_delta_pos``).

    **Observation Space:** ManiSkill's agent state plus ``extra``: ``tcp_pose``, ``goal_pos``
    (the pick goal, or the first mover's destination), ``is_grasped``, ``task_kind`` (one-hot:
    pick, place, move); in state modes also ``obj_pose``, ``tcp_to_obj_pos``, ``obj_to_goal_pos``.
    Visual modes add the 128x128 ``base_camera`` (composited over the splat with ``hybrid_obs``).

    **Rewards:** :meth:`compute_dense_reward`, in [0, its kind's ``MAX_REWARD``]; normalised [0, 1].

    **Episode End:** ``terminated`` on ``success`` or ``fail`` (ManiSkill sets it from both);
    truncation after ``MAX_EPISODE_STEPS`` (500) control steps, 10 s. Both flags are in ``info``.

    **Render modes:** ManiSkill's, and ``"hybrid"`` (``envs/rendering.py``): the env then is an
    ``rgb_array`` env (so ManiSkill's ``CPUGymWrapper``, ``RecordEpisode`` and ``FrameStack``
    take its frames unchanged) whose ``render()`` composites the human render cameras over the
    splat; ``env.unwrapped.render_hybrid`` says so.

    **Arguments:** ``__init__``'s keywords (each commented there; checked in ``envs/keywords.py``),
    ManiSkill's own, and ``config`` (YAML/JSON files merged in order, ``embodied_envs/config.py``).
    ``placement_limits`` and ``goal_region`` take the fields of ``layout/placement/limits.py``,
    ``camera_cfg`` those of ``config.CameraSpec``.
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
        init_3dgs_quat: tuple[float, float, float, float] = SPLAT_Y_UP_TO_Z_UP,
        objs_z_offset: float = 0.002,
        robot_z_offset: float = 0.002,
        camera_cfg: dict | None = None,  # camera_eye, camera_target_pt, image_hw, fovy_deg
        enable_grasp: bool = False,  # EmbodiedGen's keyword: accepted, has no effect
        hybrid_obs: bool = False,  # sensor RGB over the splat, whatever render_mode is
        hybrid_depth_test: bool = True,  # simulated pixels behind the splat surface are hidden
        splat_backend: str = "auto",  # or "torch", "gsplat"
        placement_limits: dict | PlacementLimits | None = None,
        goal_region: dict | GoalRegion | None = None,
        render_mode: str | None = None,
        **kwargs,
    ):
        # everything the user gave is checked before any simulation object exists
        self.camera_spec = CameraSpec.from_cfg(camera_cfg)
        # no eye or target given: the render camera is framed on the robot and the table
        self.frame_render_camera = not {"camera_eye", "camera_target_pt"} & set(camera_cfg or {})
        self.layout_set = LayoutSet.load(default_layout() if layout_file is None else layout_file)
        files = self.layout_set.files  # absolute
        self.layout_file = files[0] if len(files) == 1 else files
        self.base_layout: LayoutInfo = self.layout_set.layouts[0]
        if robot_uids is not None:  # a gripperless or absent robot named in its own words
            agents.check_robot(robot_uids)
        two = isinstance(robot_uids, list | tuple)  # two arms: the first at the layout's spot
        robot = keywords.one_robot(self.layout_set, robot_uids[0] if two else robot_uids)
        agents.check_robot(robot)  # its model is on this machine
        uids = tuple(robot_uids) if two else (robot,)
        self.robot_entries = tuple(robots.robot(u) for u in uids)
        self.robot_entry = self.robot_entries[0]  # the arm the task's TCP and grasp follow
        if two:  # ManiSkill's multi-agent env takes a tuple (and warns if it is not listed)
            robot, self.SUPPORTED_ROBOTS = uids, [*SUPPORTED_ROBOTS, uids]
        # reach and goals follow the robot, for each field the user did not set
        limits, goals = keywords.robot_defaults(self.robot_entry)
        self.placement_limits = dataclass_arg(
            PlacementLimits, keywords.with_defaults(placement_limits, limits), "placement_limits"
        )
        self.goal_region = dataclass_arg(
            GoalRegion, keywords.with_defaults(goal_region, goals), "goal_region"
        )
        self.goal_region.check_reach(self.placement_limits)
        for name, value in dict(
            robot_init_qpos_noise=robot_init_qpos_noise, objs_z_offset=objs_z_offset,
            robot_z_offset=robot_z_offset, replace_objs=replace_objs, enable_grasp=enable_grasp,
            hybrid_obs=hybrid_obs, hybrid_depth_test=hybrid_depth_test,
            init_3dgs_quat=init_3dgs_quat,
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
            self.layout_set.layouts,
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
        r = self.robot_entry  # eye and target given at the layout's robot spot
        drop = 0.0
        if r.base_height == "floor":  # the base stands on the floor under env 0's spot
            drop = float(self.layout_scene.robot_poses[0, 2]) - float(self.layout_scene.floor_z)
        eye, target = (r.in_base_frame(p, drop) for p in (r.camera_eye, r.camera_target))
        return [base_camera(self.main_agent, eye, target, r.camera_mount)]

    @property
    def _default_human_render_camera_configs(self):
        framing = None  # on this configuration's robot and table (env 0's)
        if self.frame_render_camera:
            framing = self.layout_scene.framing(self.render_camera_back, *self.render_camera_rise)
        return render_camera(self.camera_spec, framing)

    def _load_agent(self, options: dict):
        placed = [sapien.Pose(p=[0.0, 0.0, 0.0]) for _ in self.robot_entries]  # per episode
        super()._load_agent(options, placed if len(placed) > 1 else placed[0])

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
        entry = self.robot_entry
        span = tuple(float(np.float32(q)) for q in entry.gripper.span)  # as PhysX holds it
        spots = ls.robot_poses.cpu().numpy()
        self.task_scene = TaskScene.build(self.layouts, ls.env_actors, spots, span)
        # each arm's spot: the layout's, and for a second arm the far side of the table
        self.robot_spots = [spots]
        if len(self.robot_entries) > 1:
            top = ls.episodes.top_arrays
            self.robot_spots.append(agents.opposite_spots(
                spots, top.normals, top.offsets, top.lo, top.hi, self.placement_limits.hull_margin
            ))  # fmt: skip
        # the bases: at each env's robot spot, or by the entry's offsets from it
        self.robot_bases = [
            torch.as_tensor(r.base_poses(sp, float(ls.floor_z)), device=ls.robot_poses.device)
            for r, sp in zip(self.robot_entries, self.robot_spots, strict=True)
        ]
        self.tasks = self.task_scene.tasks  # one per env (layout/task.py)
        self.task_reader = TaskReader(self, self.task_scene, ls.top_z)
        self._kinds = sorted({t.kind for t in self.tasks}, key=KIND_IDS.get)
        self._kind_masks = {k: self.task_scene.kinds == KIND_IDS[k] for k in self._kinds}
        ls.register_state(self)
        self.ground = build_ground(self.scene, altitude=ls.floor_z)
        if entry.mobile_base:  # its wheels do not touch the ground (ManiSkill's table scene)
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

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        ls = self.layout_scene
        start = ls.episodes.draw(env_idx, self._batched_episode_rng)
        with torch.device(self.device):
            for agent, entry, bases in zip(
                agents.all_agents(self), self.robot_entries, self.robot_bases, strict=True
            ):
                agent.robot.set_root_pose(Pose.create(bases[env_idx]))
                rest = agents.rest_qpos(agent, entry)
                qpos = torch.as_tensor(rest, dtype=torch.float32).repeat(len(env_idx), 1)
                noisy = list(entry.noise_joints)  # the fingers stay open
                qpos[:, noisy] += self.robot_init_qpos_noise * start.joint_noise[:, : len(noisy)]
                agent.reset(qpos)
            ls.set_episode_poses(env_idx, start.objects if self.replace_objs else {})
            dest = self.task_reader.begin_episode(env_idx, start.goal)
            # the goal marker: the pick goal, or where the first mover goes
            is_pick = (self.task_scene.kinds == KIND_IDS["pick"]).to(self.device)[env_idx]
            goal = torch.where(is_pick[:, None], torch.as_tensor(start.goal), dest[:, 0])
            self.goal_site.set_pose(Pose.create_from_pq(goal))
        if not self.gpu_sim_enabled:  # bodies settle as in a new scene, whatever ran before
            fast_reads.restart_sleep_timers(self.scene)

    def _rules(self):
        """The task state now and each present kind's rule results (``envs/tasks``)."""
        reader = self.task_reader
        goal = self.goal_site.pose.p if reader.gpu else fast_reads.positions(self.goal_site)
        state = reader.state(goal)
        return state, {k: RULES[k].evaluate(state) for k in self._kinds}

    def _by_kind(self, results: dict, key: str) -> torch.Tensor:
        """``key`` of each env's own kind, as a tensor on the env's device."""
        out = None
        for kind, res in results.items():
            value = torch.as_tensor(res[key], device=self.device)
            if out is None:
                out = value
            else:
                mask = self._kind_masks[kind].to(self.device)
                out = torch.where(mask.reshape(-1, *[1] * (value.ndim - 1)), value, out)
        return out

    def evaluate(self):
        state, results = self._rules()
        self._last_rules = (state, results)
        info = {key: self._by_kind(results, key) for key in ("success", *INFO_KEYS)}
        ls, xp = self.layout_scene, state.xp
        movers = range(state.movers.shape[1])
        off = [ls.off_table(state.movers[:, k], self.fail_drop) for k in movers]
        # an object off the table, or the receptacle knocked off
        off.append(ls.off_table(state.rec_pos, self.fail_drop) & ~state.rec_is_table)
        info["fail"] = torch.as_tensor(xp.stack(off, 0).any(0), device=self.device)
        return info

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
        if "state" in self.obs_mode:
            obs.update(
                obj_pose=self.obj.pose.raw_pose,
                tcp_to_obj_pos=self.obj.pose.p - tcp.p,
                obj_to_goal_pos=self.goal_site.pose.p - self.obj.pose.p,
            )
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """Each env's kind's staged dense reward (``envs/tasks/<kind>.py`` ``reward``), from
        0 to that kind's ``MAX_REWARD`` (reached on success only)."""
        state, results = self._last_rules if hasattr(self, "_last_rules") else self._rules()
        rewards = {k: {"reward": RULES[k].reward(state, res)} for k, res in results.items()}
        return self._by_kind(rewards, "reward").float()

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        maxima = {k: {"max": np.full(self.num_envs, RULES[k].MAX_REWARD, np.float32)}
                  for k in self._kinds}  # fmt: skip
        return self.compute_dense_reward(obs, action, info) / self._by_kind(maxima, "max")


register(ENV_ID, PickEmbodiedGenEnv, max_episode_steps=MAX_EPISODE_STEPS)
