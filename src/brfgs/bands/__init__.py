"""Step 2 of the pipeline: geometry-reliable band selection (paper section 3.1, eqs 3–8).

    sel = select_bands(scene, strategy="efc-top3")   # BandSelection
    sel.selected            # band indices, best first
    sel.to_json()           # bands.json content (conventions.md)

Strategies of the paper's Table 2: see :mod:`brfgs.bands.select`.
"""

from brfgs.bands.efc import (equivalent_feature_count, local_median, normalise_quality, signal_quality,
                             stretch_to_uint8, top_k_bands)
from brfgs.bands.select import (STRATEGIES, TABLE2_STRATEGIES, BandSelection, BandStats, compute_band_stats,
                                plot_band_stats, select_bands)

__all__ = ["STRATEGIES", "TABLE2_STRATEGIES", "BandSelection", "BandStats", "compute_band_stats",
           "equivalent_feature_count", "local_median", "normalise_quality", "plot_band_stats", "select_bands",
           "signal_quality", "stretch_to_uint8", "top_k_bands"]
