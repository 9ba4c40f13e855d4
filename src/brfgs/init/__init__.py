"""Step 3 of the pipeline: SfM (pycolmap) or known poses → cameras and sparse points.

    from brfgs.init import initialize, InitConfig
    res = initialize(scene, band_indices, poses="known", out_dir="run/init")

pycolmap 4.2.1 breaks Python's zlib when it is imported first (np.savez_compressed and PNG
writing then abort with "free(): invalid pointer") and takes over SIGTERM: every module here
imports it through :mod:`brfgs.init.pycolmap_safe`, which guards both; ``zlib`` is also imported
here, before any submodule.
"""

import zlib  # noqa: F401  (must be imported before pycolmap)
import importlib

# Names exported here load on first use (PEP 562), so that the command line can read the options
# (brfgs.init.options) without OpenCV and the SfM code.
_EXPORTS = {"brfgs.init.options": ("POSE_MODES", "InitConfig"),
            "brfgs.init.api": ("InitResult", "initialize", "strategy_ablation", "write_points_ply")}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'brfgs.init' has no attribute {name!r}")
    return getattr(importlib.import_module(_WHERE[name]), name)
