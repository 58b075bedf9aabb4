"""Reproduction of the paper's experiments and evaluation on random forests (``experiments``, ``evaluate``).

May import both ``companion`` and ``sim_bridge``; nothing in ``companion`` imports this package except the CLI.
"""
