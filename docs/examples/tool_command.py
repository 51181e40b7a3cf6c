"""Send the gripper's TCP to a point in base_link, pointing straight down.

Run it while the graph runs, in a shell where ``source scripts/env.sh`` was done:
``python docs/examples/tool_command.py 0.4 -0.3 0.1`` (x y z in metres; these by default).
The motion node moves the arm there through the trajectory controller, or logs why not.
"""

import sys
import time

from geometry_msgs.msg import PoseStamped
import rclpy


def main() -> int:
    """Publish one tool_command once the motion node listens; return the exit code."""
    x, y, z = (float(value) for value in sys.argv[1:4]) if len(sys.argv) == 4 else (
        0.4, -0.3, 0.1)
    rclpy.init()
    node = rclpy.create_node('tool_commander')
    publisher = node.create_publisher(PoseStamped, 'tool_command', 10)
    try:
        # A message published before the two nodes have discovered each other is lost.
        deadline = time.monotonic() + 10.0
        while publisher.get_subscription_count() == 0:
            if time.monotonic() > deadline:
                print('nobody listens on tool_command: is the motion node running?')
                return 1
            time.sleep(0.1)
        target = PoseStamped()
        target.header.frame_id = 'base_link'
        target.pose.position.x, target.pose.position.y, target.pose.position.z = x, y, z
        # Half a turn about x: the TCP's z axis (out of the gripper) points down.
        target.pose.orientation.x, target.pose.orientation.w = 1.0, 0.0
        publisher.publish(target)
        print(f'sent: rg2_tcp to ({x}, {y}, {z}) m in base_link, pointing down')
        time.sleep(0.5)  # let the message go out before the node is destroyed
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
