"""Names and QoS profiles of the graph's public interface that its nodes share.

The sim (or a real robot's driver) serves these and the motion, policy, teleop and viewer nodes
(and the tests and benchmarks) use them; ``docs/interfaces.md`` is where they are defined.
Only rclpy, so any client can import this without loading the simulation.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

WORLD_FRAME = 'world'
# The six arm joints, in the order of the contract's joint_states (and of UR's driver).
ARM_JOINTS = (
    'shoulder_pan_joint',
    'shoulder_lift_joint',
    'elbow_joint',
    'wrist_1_joint',
    'wrist_2_joint',
    'wrist_3_joint',
)
# The RG2's finger joints in joint_states (after the arm's), and its gripper_cmd range.
GRIPPER_JOINTS = ('rg2_left_finger_joint', 'rg2_right_finger_joint')
RG2_MAX_OPENING = 0.110  # m, between the finger pads (RG2 datasheet)
RG2_MAX_FORCE = 40.0  # N (RG2 datasheet)
TRAJECTORY_ACTION = 'joint_trajectory_controller/follow_joint_trajectory'
GRIPPER_ACTION = 'gripper_controller/gripper_cmd'

# As tf2_ros's broadcasters and robot_state_publisher: late joiners get the latest message
# (/tf_static, robot_description, and the latched results of the motion and policy nodes).
LATCHED_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         reliability=ReliabilityPolicy.RELIABLE)
# Camera images and what is drawn on them. Large (640x480 rgb8 is 900 KiB) and across
# processes: best-effort readers lose most UDP fragments, so reliable with a short queue; a
# slow reader then costs a publisher a few frames of memory, never its pace.
IMAGE_QOS = QoSProfile(depth=5, history=HistoryPolicy.KEEP_LAST,
                       reliability=ReliabilityPolicy.RELIABLE)
# The same for a reader that only wants the newest image (vision): when a frame takes it
# longer than the camera's period, the frames that came meanwhile are dropped, not queued.
NEWEST_IMAGE_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                              reliability=ReliabilityPolicy.RELIABLE)
TF_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                    reliability=ReliabilityPolicy.RELIABLE)
# Episode markers (std_msgs/String on EPISODE_TOPIC, ur_rg2_common.episode publishes them):
# every marker counts and none is old news to a late joiner, so reliable and not latched.
EPISODE_TOPIC = 'episode'
EPISODE_START, EPISODE_SUCCESS, EPISODE_FAILURE = 'start', 'success', 'failure'
EPISODE_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
