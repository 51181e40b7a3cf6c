"""Console-script entry points: see ur_rg2_common.entry (a stop while loading is quiet)."""

from ur_rg2_common.entry import run_main


def sim() -> int:
    """Run the sim node (ur_rg2_sim.sim_node)."""
    return run_main('ur_rg2_sim.sim_node')
