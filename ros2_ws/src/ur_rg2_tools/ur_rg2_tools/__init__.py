"""Recording and replaying the graph as MCAP (ROS 2 profile), and the scene in 3D in a browser."""
