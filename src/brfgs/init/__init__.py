"""Step 3 of the pipeline: SfM (pycolmap) or known poses → cameras and sparse points.

    from brfgs.init import initialize, InitConfig
    res = initialize(scene, band_indices, poses="known", out_dir="run/init")

pycolmap 4.2.1 breaks Python's zlib when it is imported first (np.savez_compressed and PNG
writing then abort with "free(): invalid pointer"). ``zlib`` is therefore imported here,
before any submodule can import pycolmap; only :mod:`brfgs.init.colmap` imports pycolmap,
and only through this package.
"""

import zlib  # noqa: F401  (must be imported before pycolmap)

from brfgs.init.api import (POSE_MODES, InitConfig, InitResult, initialize, strategy_ablation,
                            write_points_ply)

__all__ = ["POSE_MODES", "InitConfig", "InitResult", "initialize", "strategy_ablation", "write_points_ply"]
