#!/bin/bash
# Run a command in the ROS 2 Jazzy environment with this workspace's packages.
set -e
source /opt/ros/jazzy/setup.bash
source /ws/install/setup.bash
exec "$@"
