import numpy as np
import pytest
import sapien

from embodied_envs.layout.pose import LayoutPose, quat_multiply_xyzw, yaw_quat_xyzw


def test_layout_to_sapien_reorders_quaternion():
    pose = LayoutPose.from_layout([1, 2, 3, 0.0, 0.0, 0.7071068, 0.7071068])
    sp = pose.to_sapien()
    assert isinstance(sp, sapien.Pose)
    np.testing.assert_allclose(sp.p, [1, 2, 3], atol=1e-6)
    np.testing.assert_allclose(sp.q, [0.7071068, 0, 0, 0.7071068], atol=1e-6)  # wxyz


def test_raw_round_trip_and_order():
    pose = LayoutPose.from_layout([0.1, -0.2, 0.3, 0.1, 0.2, 0.3, 0.9])
    raw = pose.to_raw()
    assert raw[3] == pytest.approx(pose.q_xyzw[3], abs=1e-6)  # raw is scalar-first
    back = LayoutPose.from_raw(raw)
    np.testing.assert_allclose(back.to_layout(), pose.to_layout(), atol=1e-6)


def test_yaw_rotates_x_axis():
    pose = LayoutPose.from_xyz_yaw([0, 0, 0], np.pi / 2)
    np.testing.assert_allclose(
        pose.transform_points(np.array([[1.0, 0, 0]])), [[0, 1, 0]], atol=1e-9
    )
    assert pose.yaw == pytest.approx(np.pi / 2)


def test_quat_multiply_applies_right_first():
    # +90 deg about X (Y-up -> Z-up) then yaw 90 deg about Z: Y axis -> Z -> Z
    q = quat_multiply_xyzw(yaw_quat_xyzw(np.pi / 2), [0.7071068, 0, 0, 0.7071068])
    pose = LayoutPose.from_layout([0, 0, 0, *q])
    np.testing.assert_allclose(
        pose.transform_points(np.array([[0, 1.0, 0]])), [[0, 0, 1]], atol=1e-6
    )
    np.testing.assert_allclose(
        pose.transform_points(np.array([[1.0, 0, 0]])), [[0, 1, 0]], atol=1e-6
    )


def test_pose_rounding_only_on_request():
    pose = LayoutPose.from_layout([0.123456, 0, 0, 0, 0, 0, 1])
    assert pose.to_layout()[0] == 0.123456
    assert pose.to_layout(4)[0] == 0.1235
