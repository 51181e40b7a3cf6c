"""Bring-up of the node graph: ``scripts/run`` starts it with ``python -m bringup``."""
