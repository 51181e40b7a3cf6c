"""The pieces every node shares, in one home: QoS profiles and transform matrices."""

from geometry_msgs.msg import Pose, Quaternion, Transform, Vector3
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
from ur_rg2_common.contract import IMAGE_QOS, LATCHED_QOS
from ur_rg2_common.tf_buffer import (
    pose_matrix,
    quaternion_from_matrix,
    set_pose,
    transform_matrix,
)


def test_images_are_reliable_with_a_short_queue_and_latched_topics_keep_the_last():
    assert (IMAGE_QOS.reliability, IMAGE_QOS.depth) == (ReliabilityPolicy.RELIABLE, 5)
    assert LATCHED_QOS.durability is DurabilityPolicy.TRANSIENT_LOCAL
    assert (LATCHED_QOS.reliability, LATCHED_QOS.depth) == (ReliabilityPolicy.RELIABLE, 1)


def test_a_transform_message_is_the_pose_matrix_of_its_translation_and_rotation():
    half = np.sqrt(0.5)  # 90 degrees about z
    transform = Transform(translation=Vector3(x=0.1, y=-0.2, z=0.3),
                          rotation=Quaternion(x=0.0, y=0.0, z=half, w=half))
    matrix = transform_matrix(transform)
    assert np.allclose(matrix, pose_matrix((0.1, -0.2, 0.3), (0.0, 0.0, half, half)))
    assert np.allclose(matrix @ [1.0, 0.0, 0.0, 1.0], [0.1, 0.8, 0.3, 1.0])
    assert np.allclose(quaternion_from_matrix(matrix), (0.0, 0.0, half, half))
    pose = Pose()
    set_pose(pose, matrix)
    assert (pose.position.x, pose.position.y, pose.position.z) == pytest.approx((0.1, -0.2, 0.3))
    assert (pose.orientation.z, pose.orientation.w) == pytest.approx((half, half))
