"""Console-script entry points: see ur_rg2_common.entry (a stop while loading is quiet)."""

from ur_rg2_common.entry import run_main


def policy() -> int:
    """Run the policy node (ur_rg2_learning.policy_node)."""
    return run_main('ur_rg2_learning.policy_node')
