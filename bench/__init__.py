"""Benchmarks of the node graph; ``python -m bench`` (``make bench``) prints the table."""
