"""Truth BRF rendered again by the simulator (Mitsuba), on the Lambertian 'flat' scene."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brfgs.analysis.brf import has_simulator_truth, truth_brf
from brfgs.analysis.roi import PolygonROI


def test_truth_brf_of_a_lambertian_field_is_isotropic_and_the_soil_spectrum(tmp_path):
    pytest.importorskip("mitsuba")
    from brfgs.sim import spectra as sp
    from brfgs.sim.acquisition import SimConfig
    from brfgs.sim.materials import material

    cfg = SimConfig.tiny("flat", bands=6, spp=16, size=16)
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "scene.json").write_text(json.dumps({"config": cfg.to_json()}))
    assert has_simulator_truth(tmp_path)
    roi = PolygonROI(np.array([[-15.0, -15.0], [15.0, -15.0], [15.0, 15.0], [-15.0, 15.0]]))  # 4 m pixels
    res = truth_brf(tmp_path, roi, [0.0, 40.0, 40.0], [0.0, 150.0, 330.0], [1, 4], distance_m=100.0, size=16)
    assert (res.n_pixels > 20).all()
    wl = cfg.wavelengths_nm()
    soil = sp.band_average(material("soil_plain").end1, wl, cfg.fwhm_array_nm())
    np.testing.assert_allclose(res.values, np.tile(soil[[1, 4]], (3, 1)), rtol=0.05)
