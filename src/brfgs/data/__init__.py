"""Step 1 of the pipeline: reading and validating a multi-angle hyperspectral scene."""

from brfgs.data.cameras import Intrinsics
from brfgs.data.scene import Frame, Scene, read_scene

__all__ = ["Frame", "Intrinsics", "Scene", "read_scene"]
