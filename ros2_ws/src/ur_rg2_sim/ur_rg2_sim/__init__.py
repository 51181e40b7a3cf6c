"""Simulated UR5/UR3 arm with an OnRobot RG2 gripper and a Kinect-like RGB-D camera (pybullet)."""
