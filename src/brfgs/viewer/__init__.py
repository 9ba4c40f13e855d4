"""The live web viewer (``brfgs view RUN``).

Pure, unit-tested pieces (no viser needed): :mod:`.cameras` (viser's browser camera ↔ brfgs's
OpenGL camera-to-world), :mod:`.formula` (band-ratio formulas parsed without ``eval``),
:mod:`.frames` (one display frame: CIR, true colour, a band, an index, depth, normals, alpha,
kernel contributions, all from :func:`brfgs.model.render`), :mod:`.roi` (a click → a disc ROI,
its spectrum, principal-plane BRF and polar map with the functions of ``brfgs brf``).
:mod:`.server` puts them on a viser page (imported only by ``brfgs view``).
"""
