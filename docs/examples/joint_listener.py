"""Print the arm's six joint angles in degrees, twice a second, until Ctrl-C.

Run it while the graph runs, in a shell where ``source scripts/env.sh`` was done:
``python docs/examples/joint_listener.py``.
"""

import math
import signal

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState


class JointListener(Node):
    """Keeps the latest joint_states (100 Hz) and shows them at a readable rate."""

    def __init__(self) -> None:
        super().__init__('joint_listener')
        self.latest = None
        self.create_subscription(JointState, 'joint_states', self.on_joint_states, 10)
        self.create_timer(0.5, self.show)

    def on_joint_states(self, msg: JointState) -> None:
        """Keep the newest message; most are never shown."""
        self.latest = msg

    def show(self) -> None:
        """Print the newest angles (the first six joints are the arm's, in order)."""
        if self.latest is not None:
            angles = zip(self.latest.name[:6], self.latest.position[:6])
            print('  '.join(f'{name.removesuffix("_joint")} {math.degrees(rad):+7.1f}'
                            for name, rad in angles), flush=True)


def main() -> None:
    """Listen until Ctrl-C."""
    # Ctrl-C only ends the loop below. A KeyboardInterrupt could land while rclpy converts a
    # message, where it comes out as a RuntimeError and a traceback.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stopped = []
    signal.signal(signal.SIGINT, lambda *_: stopped.append(True))
    node = JointListener()
    try:
        # A bounded wait rather than rclpy.spin(): Ctrl-C is noticed within 0.25 s.
        while not stopped and rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.25)
    except ExternalShutdownException:
        pass  # the context was shut down from outside: a clean exit too
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
