"""Workflows that chain training and analysis: the paper's ablation tables and the demo.

The layer above :mod:`brfgs.train` and :mod:`brfgs.analysis` (which never import each other).
"""
