"""Cartesian control of the UR + RG2 (closed-form UR kinematics) and the vision-guided pick."""
