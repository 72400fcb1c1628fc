"""Tests of ``lodestar.ground.wcs``: catalogue stars round-trip through the FITS header
(read back by astropy.wcs) to the pixels the camera model puts them at."""

import warnings

import numpy as np
import pytest
from astropy.io import fits
from astropy.wcs import WCS, FITSFixedWarning
from scipy.spatial.transform import Rotation

from lodestar.ground import wcs as _wcs
from lodestar.ground.onboard import firmware_camera
from lodestar.sim.attitude import from_radec_roll
from lodestar.sim.catalogue import load
from lodestar.sim.presets import load_preset


def _stars_in_frame(q, camera, pointing):
    """``(ra, dec, x, y)`` of the V <= 7 stars the camera model puts inside the frame."""
    cat = load().brighter_than(7.0).cone(pointing[0], pointing[1], 30.0)
    v_cam = Rotation.from_quat(q).apply(cat.unit_vectors())
    rows = []
    for i, v in enumerate(v_cam.tolist()):
        px = camera.vector_to_pixel(v)
        if px is not None and 0 <= px[0] <= camera.width - 1 and 0 <= px[1] <= camera.height - 1:
            rows.append((cat.ra_deg[i], cat.dec_deg[i], px[0], px[1]))
    return np.array(rows)


@pytest.mark.parametrize("preset, binning, bound_px", [("estcube2", 1, 1e-6),
                                                      ("lohmann", 1, 0.05),
                                                      ("lohmann", 2, 0.1)])
@pytest.mark.parametrize("pointing", [(83.8, -5.4, 30.0), (10.0, 88.0, -120.0),
                                      (250.0, -60.0, 200.0)])
def test_star_pixels_round_trip(tmp_path, preset, binning, bound_px, pointing):
    """Stars projected by the camera model and by astropy from the written header agree
    (lohmann: k1 = -0.37, through SIP) in the image's pixels, also for a binned frame."""
    camera = firmware_camera(load_preset(preset))
    q = from_radec_roll(*pointing)
    stars = _stars_in_frame(q, camera, pointing)
    assert len(stars) >= 5
    header, residual = _wcs.wcs_header(q, camera, camera.width, camera.height, binning)
    assert residual < bound_px
    path = tmp_path / "frame.wcs"
    path.write_bytes(_wcs.header_bytes(header))
    with fits.open(path) as hdul, warnings.catch_warnings():
        warnings.simplefilter("ignore", FITSFixedWarning)   # NAXIS = 0: a header-only file
        wcs = WCS(hdul[0].header)
    assert wcs.has_distortion == (preset == "lohmann")
    n = binning
    want_x, want_y = n * stars[:, 2] + (n - 1) / 2, n * stars[:, 3] + (n - 1) / 2
    x, y = wcs.all_world2pix(stars[:, 0], stars[:, 1], 0)
    assert np.max(np.hypot(x - want_x, y - want_y)) < bound_px + 1e-6
    ra, dec = wcs.all_pix2world(want_x, want_y, 0)
    sep = np.degrees(np.arccos(np.clip(
        np.sin(np.radians(dec)) * np.sin(np.radians(stars[:, 1])) +
        np.cos(np.radians(dec)) * np.cos(np.radians(stars[:, 1])) *
        np.cos(np.radians(ra - stars[:, 0])), -1, 1))) * 3600
    scale = 206265 / camera.fx * n                         # arcsec per image pixel
    assert np.max(sep) < (bound_px + 1e-3) * scale
