"""Mutations of brfgs's inputs for scripts/fuzz_inputs.py, one module per surface (scene, sidecar, roi, sun)."""
