"""``evaluate()`` and the dense reward read numpy arrays on the CPU simulation and tensors on
the GPU (``TaskState``), by one set of rules written for both. On every shipped layout, at
every step of an expert episode and after a drop, the flags from tensors (read through
ManiSkill's ``Actor``, ``Link`` and ``Articulation``, as on the GPU) equal those from arrays
and the rewards agree to float32 rounding."""

import numpy as np
import torch
from conftest import per_layout_env

import embodied_envs  # noqa: F401
from embodied_envs.envs.pick_embodiedgen import TaskState
from embodied_envs.solvers import PickPlaceSolver

env = per_layout_env(control_mode="pd_joint_pos")


def test_arrays_and_tensors_give_the_same_flags_and_rewards(env):
    u = env.unwrapped
    arrays = u._task_state

    def tensors():  # the state as the GPU simulation reads it: ManiSkill's structs, tensors
        qvel = u.agent.robot.get_qvel()[..., :-2]
        return TaskState(u.obj.pose.p, u.goal_site.pose.p, u.agent.tcp_pose.p, qvel)

    evaluate, seen = u.evaluate, []

    def checked():
        info = evaluate()
        reward = u.compute_dense_reward(None, None, info)
        assert isinstance(arrays().obj, np.ndarray)  # the CPU simulation reads arrays
        u._task_state = tensors
        try:
            info_t = evaluate()
            reward_t = u.compute_dense_reward(None, None, info_t)
        finally:
            u._task_state = arrays
        assert list(info) == list(info_t)
        for key, value in info.items():
            assert value.dtype == info_t[key].dtype and value.shape == info_t[key].shape, key
            assert value.device == info_t[key].device, key
            assert torch.allclose(value.float(), info_t[key].float(), atol=1e-7), key
        assert reward.dtype == reward_t.dtype == torch.float32 and reward.shape == (1,)
        assert torch.allclose(reward, reward_t, atol=1e-6), (reward, reward_t)
        seen.append([float(reward[0])] + [bool(info[k][0]) for k in ("success", "is_grasped")])
        return info

    u.evaluate = checked
    try:
        env.reset(seed=0)
        PickPlaceSolver(env, seed=0).solve()
        for _ in range(15):  # open the fingers at the goal: the object falls
            env.step(np.r_[u.agent.robot.get_qpos()[0, :7].cpu().numpy(), 1.0])
    finally:
        u.evaluate = evaluate
    reward, success, grasped = np.array(seen).T
    assert len(seen) > 60
    # every stage of the reward occurs: reaching only, grasped, success (its maximum)
    assert reward.min() < 1 and grasped.any() and (~grasped.astype(bool)).any()
    assert success.any() and reward.max() == u.max_reward
