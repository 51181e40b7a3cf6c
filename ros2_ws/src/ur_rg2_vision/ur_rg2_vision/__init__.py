"""Frame saving and 3D ball detection for the UR + RG2 simulation camera."""
