"""Matplotlib for the figure writers of every step (PNG/PDF files, never a window)."""

from __future__ import annotations

import zlib  # noqa: F401  (PNG writing needs a sane zlib: import it before anything that may pull pycolmap)


def pyplot():
    """``matplotlib.pyplot`` with the non-interactive Agg backend selected."""
    import matplotlib  # lazy: choosing Agg at import would switch the backend of any program importing brfgs

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt  # lazy: ~0.6 s to import, and only after the backend is chosen

    return plt
