"""Console-script entry points: see ur_rg2_common.entry (a stop while loading is quiet)."""

from ur_rg2_common.entry import run_main


def rg2_adapter() -> int:
    """Run the RG2 adapter node (ur_rg2_hardware.rg2_adapter)."""
    return run_main('ur_rg2_hardware.rg2_adapter')
