"""Console-script entry points: see ur_rg2_common.entry (a stop while loading is quiet)."""

from ur_rg2_common.entry import run_main


def record() -> int:
    """Run the recorder (ur_rg2_tools.record_node)."""
    return run_main('ur_rg2_tools.record_node')


def replay() -> int:
    """Run the player (ur_rg2_tools.replay_node)."""
    return run_main('ur_rg2_tools.replay_node')


def recover() -> int:
    """Recover the complete chunks of a cut-short recording (ur_rg2_tools.recover)."""
    return run_main('ur_rg2_tools.recover')


def info() -> int:
    """Print what ``ros2 bag info`` prints about a recording (ur_rg2_tools.info)."""
    return run_main('ur_rg2_tools.info')


def to_lerobot() -> int:
    """Write recordings as a LeRobot data set (ur_rg2_tools.to_lerobot)."""
    return run_main('ur_rg2_tools.to_lerobot')


def demos() -> int:
    """Record N pick episodes of the running graph (ur_rg2_tools.demos_node)."""
    return run_main('ur_rg2_tools.demos_node')


def view3d() -> int:
    """Run the 3D view (ur_rg2_tools.view3d_node)."""
    return run_main('ur_rg2_tools.view3d_node')
