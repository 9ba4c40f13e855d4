"""Products of a trained model for remote-sensing tools: maps.py (kernel contribution maps, NBAR,
albedo, anisotropy), mcd43_maps.py (MODIS MCD43-style f_iso/f_vol/f_geo), georaster.py (GeoTIFF and
ENVI map info), report.py (``brfgs products``: every map written), export.py (3DGS PLY)."""
