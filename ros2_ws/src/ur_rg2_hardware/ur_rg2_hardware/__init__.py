"""The real robot's side of the graph (ur_rg2_hardware.rg2_adapter)."""
