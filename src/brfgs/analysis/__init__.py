"""Analysis of a trained model (:class:`brfgs.model.TrainedModel`, rendered by :func:`brfgs.model.render`).

Library: metrics.py (PSNR/SSIM/LPIPS on CIR, SAM), evaluate.py (metrics of a run's test views),
views.py (cameras, hemisphere grids, paths), roi.py / polygons.py / roi_spec.py (regions of
interest, GeoJSON, ``--roi``), brf.py (BRF curves, polar maps, observations), truth.py (the
simulator's truth BRF), products.py (kernel maps, NBAR, albedo, ANIX), export.py (3DGS PLY),
plots.py (figures, CSV), bench.py (timings), threads.py, options.py, output.py.

One function per command writes its report (CSV, JSON, PNG, ENVI): brf_report.brf_report,
render_report.render_report, products_report.products_report, export.export_model.
"""
