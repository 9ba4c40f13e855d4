"""BRF analysis of a trained model (:class:`brfgs.model.TrainedModel`, rendered by :func:`brfgs.model.render`).

views.py (cameras, hemisphere grids, paths), roi.py / polygons.py / roi_spec.py (regions of
interest, GeoJSON, ``--roi``), brf.py (BRF curves, polar maps, observations), truth.py (the
simulator's truth BRF), plots.py (figures, CSV), bench.py (timings), threads.py, options.py,
output.py (output folders). One function per command writes its report (CSV, JSON, PNG, ENVI):
brf_report.brf_report, render_report.render_report. Scores of held-out views are in
:mod:`brfgs.evaluation`, maps and files for other tools in :mod:`brfgs.products`.
"""
