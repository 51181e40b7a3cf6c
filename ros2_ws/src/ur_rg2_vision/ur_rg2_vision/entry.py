"""Console-script entry points: see ur_rg2_common.entry (a stop while loading is quiet)."""

from ur_rg2_common.entry import run_main


def vision() -> int:
    """Run the vision node (ur_rg2_vision.vision_node)."""
    return run_main('ur_rg2_vision.vision_node')


def viewer() -> int:
    """Run the viewer node (ur_rg2_vision.viewer_node)."""
    return run_main('ur_rg2_vision.viewer_node')


def dataset() -> int:
    """Run the dataset node (ur_rg2_vision.dataset_node)."""
    return run_main('ur_rg2_vision.dataset_node')
