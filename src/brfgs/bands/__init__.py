"""Step 2 of the pipeline: geometry-reliable band selection (paper section 3.1, eqs 3–8).

    sel = select_bands(scene, strategy="efc-top3")   # BandSelection
    sel.selected            # band indices, best first
    sel.to_json()           # bands.json content (docs/data-format.md)

Strategies of the paper's Table 2: see :mod:`brfgs.bands.select`.
"""

import importlib

# Names exported here load on first use (PEP 562), so that the command line can read the options
# (brfgs.bands.options) without OpenCV.
_EXPORTS = {
    "brfgs.bands.efc": ("equivalent_feature_count", "local_median", "normalise_quality", "signal_quality",
                        "stretch_to_uint8", "top_k_bands"),
    "brfgs.bands.select": ("TABLE2_STRATEGIES", "BandSelection", "BandStats", "compute_band_stats",
                           "plot_band_stats", "select_bands"),
    "brfgs.bands.options": ("STRATEGIES", "SelectBandsOptions"),
}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'brfgs.bands' has no attribute {name!r}")
    return getattr(importlib.import_module(_WHERE[name]), name)
