"""Workflows that chain training and analysis: the paper's ablation tables, the demo, and batches of
scenes as Ray tasks (``brfgs batch``).

The layer above :mod:`brfgs.train` and :mod:`brfgs.analysis` (which never import each other).
"""
