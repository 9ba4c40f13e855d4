"""Analysis: evaluation metrics (metrics.py), BRF curves, products and export."""
