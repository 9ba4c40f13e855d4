"""brfgs: hyperspectral bidirectional reflectance modelling with 3D Gaussian splatting.

Implements BRF-GS (see docs/architecture.md for the flow of one scene through the package).
"""

__version__ = "0.2.0"
