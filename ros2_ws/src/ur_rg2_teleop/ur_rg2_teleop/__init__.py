"""Terminal keyboard teleoperation for the UR + RG2 simulation."""
