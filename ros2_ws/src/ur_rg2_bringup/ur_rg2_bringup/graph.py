"""What graph.launch.py and the ``graph`` executable share: the keys node, how a process ended.

Plain data and functions, no launch import.
"""

from __future__ import annotations

from dataclasses import dataclass
import signal


@dataclass(frozen=True)
class GraphNode:
    """One node: its package, executable and ROS node name."""

    package: str
    executable: str
    node_name: str


# The keyboard teleop, which the graph executable runs beside launch: it needs the terminal.
KEYS = GraphNode('ur_rg2_teleop', 'keys', 'ur_rg2_teleop')


def describe_exit(returncode: int) -> str:
    """Say how a process ended, from its return code (negative: the signal that killed it)."""
    if returncode >= 0:
        return f'exited with code {returncode}'
    try:
        name = signal.Signals(-returncode).name
    except ValueError:
        name = 'unknown signal'
    return f'was killed by signal {-returncode} ({name})'
