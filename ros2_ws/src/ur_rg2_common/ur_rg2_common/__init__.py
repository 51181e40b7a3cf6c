"""What every node of the UR + RG2 graph shares, with the simulator or with a real robot.

The contract's names and QoS, the arm's joint names, parameter declaration, the process entry
point, a transform buffer and the camera's optical frame. Only rclpy and NumPy: nothing here
loads the simulator or pybullet.
"""
