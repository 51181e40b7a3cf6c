"""The learned ball detector without ROS: network, rendered scenes, data sets, training.

Nothing here imports rclpy; torch is imported only where a network is built or trained.
"""
