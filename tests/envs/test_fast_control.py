"""``envs/fast_control.py`` gives exactly ManiSkill's ``set_action``: two CPU envs per robot,
one with the fast path (the env's default) and one with ManiSkill's, stepped with the same
seeded actions (in range, out of range, zeros, signed zeros) in each joint control mode, agree
bit for bit after every step on every joint's drive and velocity target and on the controller's
state, and on the joint positions; NaN actions are refused as ManiSkill refuses them."""

import copy
import types

import gymnasium as gym
import numpy as np
import pytest
import torch
from mani_skill.agents.controllers.base_controller import CombinedController

import embodied_envs  # noqa: F401
from embodied_envs.envs import fast_control

ROBOTS = ("panda", "panda_wristcam", "so100", "koch-v1.1", "fetch")
STEPS = 12  # control steps per mode
STATE = ("_step", "_start_qpos", "_target_qpos", "_step_size", "_target_qvel")


def env_pair(uid: str):
    """A fast env and a ManiSkill one, built alike."""
    pair = [gym.make("PickEmbodiedGen-v1", obs_mode="none", robot_uids=uid) for _ in range(2)]
    fast, slow = (e.unwrapped.agent for e in pair)
    assert fast_control.installed(fast) and fast_control.installed(slow)
    fast_control.uninstall(slow)
    assert not fast_control.installed(slow)
    return pair


@pytest.fixture(scope="module", params=ROBOTS)
def pair(request):
    envs = env_pair(request.param)
    yield envs
    for e in envs:
        e.close()


def sub_controllers(agent) -> dict:
    c = agent.controller
    return dict(getattr(c, "controllers", {"_": c}))


def exact(values) -> bytes:
    """Float32 values as bytes: signed zeros differ, NaNs are one NaN. The Fetch's
    ``pd_joint_pos_vel`` scales its continuous joints' infinite limits to NaN targets
    (ManiSkill's too); its NaN physics then gives NaNs of either sign bit."""
    values = np.array(values, dtype=np.float32)
    values[np.isnan(values)] = np.nan
    return values.tobytes()


def drives(agent) -> bytes:
    """Every active joint's drive target and velocity target."""
    joints = agent.robot._objs[0].active_joints
    return exact([np.concatenate([j.drive_target, j.drive_velocity_target]) for j in joints])


def controller_state(agent) -> dict:
    """Each sub-controller's state ManiSkill keeps: values, dtypes and shapes."""
    out = {}
    for uid, c in sub_controllers(agent).items():
        for name in STATE:
            v = getattr(c, name, None)
            if isinstance(v, torch.Tensor):
                v = (str(v.dtype), tuple(v.shape), exact(v.numpy()))
            out[f"{uid}.{name}"] = v
    return out


def actions(space, rng, n: int) -> list[torch.Tensor]:
    """``n`` actions: uniform over the box widened 30% each side (out of range), with every
    fifth all zeros, some entries -0.0 and some exactly at the bounds."""
    lo = np.nan_to_num(space.low.astype(np.float64), neginf=-3.0)
    hi = np.nan_to_num(space.high.astype(np.float64), posinf=3.0)
    out = []
    for k in range(n):
        a = (lo + (hi - lo) * rng.uniform(-0.3, 1.3, lo.shape)).astype(np.float32)
        if k % 5 == 0:
            a[:] = 0
        elif k % 5 == 1:
            a[rng.random(a.shape) < 0.3] = -0.0
        elif k % 5 == 2:
            a = np.where(rng.random(a.shape) < 0.5, lo, hi).astype(np.float32)
        out.append(torch.from_numpy(a)[None])
    return out


def switch(envs, mode: str, seed: int) -> None:
    for e in envs:
        agent = e.unwrapped.agent
        agent.set_control_mode(mode)
        agent.controller.set_drive_property()  # a mode's gains, as when it is first made
        e.reset(seed=seed)


def assert_same_steps(envs, seed: int) -> None:
    fast, slow = (e.unwrapped.agent for e in envs)
    rng = np.random.default_rng(seed)
    for k, action in enumerate(actions(slow.single_action_space, rng, STEPS)):
        for e in envs:  # ManiSkill's way to step in a mode the env was not made with
            e.step({"control_mode": slow.control_mode, "action": action.clone()})
        where = f"{slow.control_mode} step {k}"
        assert drives(fast) == drives(slow), where
        assert controller_state(fast) == controller_state(slow), where
        assert fast.get_controller_state().keys() == slow.get_controller_state().keys()
    qpos = [e.unwrapped.agent.robot._objs[0].qpos for e in envs]
    assert exact(qpos[0]) == exact(qpos[1]), slow.control_mode
    assert not np.array_equal(qpos[0], envs[0].unwrapped.agent.robot._objs[0].qpos * 0)


def test_each_joint_mode_gives_maniskills_targets_state_and_qpos(pair):
    agent = pair[0].unwrapped.agent
    modes = [m for m in agent.supported_control_modes if "joint" in m]
    assert "pd_joint_pos" in modes and "pd_joint_delta_pos" in modes
    for seed, mode in enumerate(modes):
        switch(pair, mode, seed)
        plan = agent.set_action.plan()
        assert all(c.endswith("True") for c in plan.covered), plan.covered  # all fast
        assert_same_steps(pair, seed)


def test_the_fetch_base_turned_every_way_gives_maniskills_velocities(pair):
    """The base's velocity targets at yaws all round (signed zeros from a zero forward speed
    at every sign of the yaw's sine and cosine)."""
    switch(pair, "pd_joint_delta_pos", 0)
    agents = [e.unwrapped.agent for e in pair]
    base = sub_controllers(agents[0]).get("base")
    if base is None:
        pytest.skip("no base velocity controller")
    yaw_index = int(base.active_joint_indices[2])
    rng = np.random.default_rng(7)
    space = agents[0].single_action_space
    moves = [*actions(space, rng, 5), torch.zeros((1, *space.shape)) * -1.0]
    for yaw in [*np.linspace(-np.pi, np.pi, 17), *rng.uniform(-7, 7, 8)]:
        for action in moves:
            for agent in agents:
                qpos = agent.robot._objs[0].qpos
                qpos[yaw_index] = yaw
                agent.robot._objs[0].qpos = qpos
                agent.set_action(action.clone())
            assert drives(agents[0]) == drives(agents[1]), yaw


def test_nan_refused_as_maniskill_refuses_it(pair):
    switch(pair, "pd_joint_delta_pos", 0)
    action = torch.zeros((1, *pair[0].unwrapped.agent.single_action_space.shape))
    action[0, 0] = float("nan")
    errors = []
    for e in pair:
        before = drives(e.unwrapped.agent)
        with pytest.raises(ValueError) as err:
            e.unwrapped.agent.set_action(action)
        assert drives(e.unwrapped.agent) == before  # nothing written
        errors.append(err.value.args[0])
    assert errors == ["Action cannot be NaN. Environment received:"] * 2


@pytest.fixture(scope="module")
def panda_pair():
    envs = env_pair("panda")
    yield envs
    for e in envs:
        e.close()


def add_mode(envs, name: str, base: str, **flags) -> None:
    """A control mode ``base`` with ``flags`` changed (sub-controller -> {flag: value}), made
    as ``BaseAgent.set_control_mode`` makes a mode's controller."""
    for e in envs:
        agent = e.unwrapped.agent
        configs = copy.deepcopy(agent._controller_configs[base])  # a property: new configs
        configs.pop("balance_passive_force", None)
        for uid, changes in flags.items():
            for flag, value in changes.items():
                setattr(configs[uid], flag, value)
        agent.controllers[name] = CombinedController(
            configs, agent.robot, agent._control_freq, scene=agent.scene
        )
        agent.supported_control_modes.append(name)


@pytest.mark.parametrize(
    "base,flags",
    [
        ("pd_joint_target_delta_pos", dict(  # interpolation; the mimic gripper by target delta
            arm=dict(interpolate=True),
            gripper=dict(use_delta=True, use_target=True, interpolate=True))),
        ("pd_joint_delta_pos_vel", dict(  # position-velocity by target delta, interpolated
            arm=dict(use_target=True, interpolate=True), gripper=dict(use_delta=True))),
        ("pd_joint_pos", dict(arm=dict(interpolate=True))),
    ],
)  # fmt: skip
def test_config_variants_no_robot_uses_give_maniskills_results(panda_pair, base, flags):
    name = f"variant_{base}_{len(panda_pair[0].unwrapped.agent.supported_control_modes)}"
    add_mode(panda_pair, name, base, **flags)
    switch(panda_pair, name, 3)
    assert all(c.endswith("True") for c in panda_pair[0].unwrapped.agent.set_action.plan().covered)
    assert_same_steps(panda_pair, 3)


def test_uncovered_controllers_keep_maniskills_set_action(panda_pair):
    """An end-effector arm controller stays ManiSkill's, its gripper fast, the result the same;
    a float64 action or a numpy one goes to ManiSkill's set_action whole."""
    switch(panda_pair, "pd_ee_delta_pose", 5)
    assert panda_pair[0].unwrapped.agent.set_action.plan().covered == [
        "PDEEPoseController: False", "PDJointPosMimicController: True",
    ]  # fmt: skip
    assert_same_steps(panda_pair, 5)
    switch(panda_pair, "pd_joint_delta_pos", 6)
    fast, slow = (e.unwrapped.agent for e in panda_pair)
    for action in (torch.full((1, 8), 0.5, dtype=torch.float64), np.full((1, 8), -0.5, "f4")):
        for agent in (fast, slow):
            try:
                agent.set_action(action)
            except Exception as err:  # ManiSkill's own answer to it, whatever it is
                agent.error = repr(err)
        assert drives(fast) == drives(slow)
        assert getattr(fast, "error", None) == getattr(slow, "error", None)


def test_two_arms_each_get_the_fast_path_with_maniskills_results():
    """ManiSkill's multi-agent env: each arm's set_action is the fast one, with its results."""
    envs = [gym.make("PickEmbodiedGen-v1", obs_mode="none", robot_uids=("panda", "so100"))]
    envs.append(gym.make("PickEmbodiedGen-v1", obs_mode="none", robot_uids=("panda", "so100")))
    arms = [e.unwrapped.agent.agents for e in envs]
    assert all(fast_control.installed(a) for a in arms[0] + arms[1])
    for a in arms[1]:
        fast_control.uninstall(a)
    for e in envs:
        e.reset(seed=1)
    rng = np.random.default_rng(0)
    spaces = envs[0].unwrapped.single_action_space.spaces
    for k in range(STEPS):
        action = {u: rng.uniform(-1.3, 1.3, s.shape).astype(np.float32) for u, s in spaces.items()}
        for e in envs:
            e.step({u: v.copy() for u, v in action.items()})
        for fast, slow in zip(*arms, strict=True):
            assert drives(fast) == drives(slow), k
            assert controller_state(fast) == controller_state(slow), k
    for e in envs:
        e.close()


def test_install_skips_the_gpu_and_batched_scenes():
    for gpu, n in ((True, 1), (False, 4)):
        fake = types.SimpleNamespace(scene=types.SimpleNamespace(gpu_sim_enabled=gpu, num_envs=n))
        assert fast_control.install(fake) is False
        assert "set_action" not in vars(fake)
