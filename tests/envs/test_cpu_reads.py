"""What the CPU simulation reads every step from the SAPIEN objects directly, without
ManiSkill's torch wrapping, gives what ManiSkill's own reads give:

- ``evaluate()`` and the dense reward read numpy arrays on the CPU simulation and tensors on
  the GPU (``envs/tasks`` ``TaskState``, read by ``TaskReader``), by one set of rules written
  for both: the flags from tensors (read
  through ManiSkill's ``Actor``, ``Link`` and ``Articulation``, as on the GPU) equal those from
  arrays and the rewards agree to float32 rounding;
- ``get_state_dict()`` (recorded by ``RecordEpisode`` every step) equals ManiSkill's
  ``BaseEnv.get_state_dict`` bit for bit, and ``set_state_dict`` takes it back.

On every shipped layout, at every step of an expert episode and after a drop."""

import numpy as np
import torch
from conftest import REWARD_FALL_TOL, per_layout_env
from mani_skill.envs.sapien_env import BaseEnv

import embodied_envs  # noqa: F401
from embodied_envs.envs.tasks import RULES
from embodied_envs.envs.tasks.scene import TaskReader
from embodied_envs.solvers import PickPlaceSolver

env = per_layout_env(control_mode="pd_joint_pos")


def expert_episode_then_drop(env, seed: int, evaluate, before_drop=None) -> None:
    """An expert episode, then 15 steps with the fingers open at the goal (the object falls),
    with ``evaluate`` (which calls the env's own) in place of the env's ``evaluate()``;
    ``before_drop()`` is called between the two."""
    u = env.unwrapped
    own = u.evaluate
    u.evaluate = evaluate
    try:
        env.reset(seed=seed)
        PickPlaceSolver(env, seed=seed).solve()
        if before_drop is not None:
            before_drop()
        for _ in range(15):
            env.step(np.r_[u.agent.robot.get_qpos()[0, :7].cpu().numpy(), 1.0])
    finally:
        u.evaluate = own


def test_arrays_and_tensors_give_the_same_flags_and_rewards(env):
    u = env.unwrapped
    evaluate, seen = u.evaluate, []

    def checked():
        info = evaluate()
        reward = u.compute_dense_reward(None, None, info)
        arrays = u.task_reader
        assert isinstance(arrays.state(np.zeros((1, 3))).tcp, np.ndarray)  # the CPU reads arrays
        # the state as the GPU simulation reads it: ManiSkill's structs, tensors
        u.task_reader = TaskReader(u, u.task_scene, u.layout_scene.top_z, tensors=True)
        u.task_reader.start = torch.as_tensor(arrays.start)
        u.task_reader.dest = torch.as_tensor(arrays.dest)
        u.task_reader.fresh = torch.as_tensor(arrays.fresh)
        if arrays.step_start is not None:  # the arm's joints when the step began
            u.task_reader.step_start = torch.as_tensor(arrays.step_start)
        try:
            info_t = evaluate()
            reward_t = u.compute_dense_reward(None, None, info_t)
        finally:
            u.task_reader = arrays
        assert list(info) == list(info_t)
        for key, value in info.items():
            assert value.dtype == info_t[key].dtype and value.shape == info_t[key].shape, key
            assert value.device == info_t[key].device, key
            assert torch.allclose(value.float(), info_t[key].float(), atol=1e-7), key
        assert reward.dtype == reward_t.dtype == torch.float32 and reward.shape == (1,)
        assert torch.allclose(reward, reward_t, atol=1e-6), (reward, reward_t)
        seen.append([float(reward[0])] + [bool(info[k][0]) for k in ("success", "is_grasped")])
        return info

    expert_end = []
    expert_episode_then_drop(env, 0, checked, lambda: expert_end.append(len(seen)))
    reward, success, grasped = np.array(seen).T
    assert len(seen) > 60
    # every stage of the reward occurs: reaching only, grasped, success (its maximum)
    assert reward.min() < 1 and grasped.any() and (~grasped.astype(bool)).any()
    top = RULES[u.tasks[0].kind].MAX_REWARD
    assert success.any() and reward.max() == top
    # the normalised reward rises along the expert's episode: it ends at 1 and never falls by
    # more than the tolerance between evaluations
    expert = reward[: expert_end[0]] / top
    assert expert[-1] == 1.0 and (-np.diff(expert)).max() <= REWARD_FALL_TOL


def test_state_dict_is_maniskills_bit_for_bit(env):
    u = env.unwrapped
    evaluate, steps = u.evaluate, []

    def same(a, b, path="state"):
        assert type(a) is type(b), path
        if isinstance(a, dict):
            assert list(a) == list(b), (path, list(a), list(b))
            for key in a:
                same(a[key], b[key], f"{path}/{key}")
        else:
            assert a.dtype == b.dtype and a.shape == b.shape and a.device == b.device, path
            assert torch.equal(a, b), (path, a, b)

    def checked():
        ours = u.get_state_dict()
        same(ours, BaseEnv.get_state_dict(u))
        steps.append(ours)
        return evaluate()

    expert_episode_then_drop(env, 1, checked)
    assert len(steps) > 60
    name = u.layouts[0].target_node  # the state dict holds each node's actor by its name
    moved = steps[len(steps) // 2]["actors"][name]
    assert not torch.equal(moved, steps[0]["actors"][name])  # the target was carried
    assert moved[0, 7:].abs().max() > 0  # with a velocity
    u.set_state_dict(steps[len(steps) // 2])  # ManiSkill's setter takes it back (PhysX
    back = u.get_state_dict()  # renormalises the quaternions it is given: to 1e-6)
    for group in ("actors", "articulations"):
        for key, value in steps[len(steps) // 2][group].items():
            assert torch.allclose(back[group][key], value, atol=1e-6), key
