"""The UR + RG2 node graph: its launch arguments and the graph executable."""
