"""FITS world coordinates of a solution (``lodestar solve --wcs FILE``): a header that
astronomy tools (astropy.wcs, ds9, astrometry.net's ``.wcs`` readers) use to overlay the
sky on the image.

Model: gnomonic (``TAN``) about the camera's principal point: ``CRVAL`` is the direction of
the optical axis (ICRS, degrees), ``CRPIX`` the principal point (FITS pixels: 1-based, the
first pixel's centre at 1.0, i.e. lodestar pixel + 1), ``CD`` maps pixel offsets to
intermediate world coordinates in degrees (east and north on the tangent plane).  A pinhole
camera is exactly this.  When the camera distorts (Brown-Conrady), ``TAN-SIP`` polynomials
(Shupe et al. 2005) of order :data:`SIP_ORDER` carry the distortion: ``A, B`` (pixel ->
undistorted) and the inverse ``AP, BP``, least-squares fits on a :data:`GRID` x ``GRID``
grid over the frame; the header states the largest fit residual (px).
Pixels of a binned frame (``bin`` n) map back to the original image as
:meth:`lodestar.ground.imagesolve.SkyImage.to_original` does.
"""

import io
import math

import numpy as np
from scipy.spatial.transform import Rotation

SIP_ORDER = 4
"""Order of the SIP polynomials (5-term radial Brown-Conrady to < 0.05 px on the presets)."""
GRID = 33
"""Fit points per axis."""


def _radec(v):
    ra = math.degrees(math.atan2(v[1], v[0])) % 360.0
    return ra, math.degrees(math.asin(max(-1.0, min(1.0, v[2]))))


def _terms(order, low):
    return [(p, t - p) for t in range(low, order + 1) for p in range(t, -1, -1)]


def _poly(u, v, terms):
    return np.stack([u ** p * v ** q for p, q in terms], axis=1)


def wcs_header(q, camera, width, height, binning=1, sip_order=SIP_ORDER):
    """``(astropy.io.fits.Header, residual_px)`` of attitude ``q`` (``[x, y, z, w]``,
    ``v_cam = A(q) v_icrs``) for a firmware ``camera`` of a ``width`` x ``height`` frame
    that is the image binned ``binning`` x ``binning`` (the header is in the image's
    pixels).  ``residual_px``: largest SIP fit error on the grid (0 without distortion).
    Raises ``ValueError`` when the camera model cannot map the frame's corners."""
    from astropy.io import fits

    n = float(binning)
    to_cam = Rotation.from_quat(np.asarray(q, dtype=float)).inv()
    axis = to_cam.apply([0.0, 0.0, 1.0])
    ra0, dec0 = _radec(axis)
    east = np.array([-math.sin(math.radians(ra0)), math.cos(math.radians(ra0)), 0.0])
    north = np.cross(axis, east)
    # grid in binned pixels -> ICRS -> tangent-plane degrees
    xs = np.linspace(-0.5, width - 0.5, GRID)
    ys = np.linspace(-0.5, height - 0.5, GRID)
    gx, gy = (a.ravel() for a in np.meshgrid(xs, ys))
    vec = []
    for x, y in zip(gx.tolist(), gy.tolist()):
        v = camera.pixel_to_vector(x, y)
        if v is None:
            raise ValueError(f"the camera model cannot map pixel ({x:.1f}, {y:.1f})")
        vec.append(v)
    sky = to_cam.apply(np.array(vec))
    depth = sky @ axis
    world = np.degrees(np.stack([sky @ east / depth, sky @ north / depth], axis=1))
    # image pixel offsets from the principal point (original image pixels)
    u = n * (gx - camera.cx)
    w = n * (gy - camera.cy)
    # the pinhole part: normalised coordinates (x - cx) / fx scale into the tangent plane
    # by the rotation between camera axes and (east, north)
    cam_x, cam_y = to_cam.apply([1.0, 0.0, 0.0]), to_cam.apply([0.0, 1.0, 0.0])
    rot = np.degrees(np.array([[cam_x @ east, cam_y @ east], [cam_x @ north, cam_y @ north]]))
    cd = rot @ np.diag([1.0 / (n * camera.fx), 1.0 / (n * camera.fy)])
    undist = np.linalg.solve(cd, world.T).T                 # pixel offsets without distortion
    distorts = any(getattr(camera, k) != 0.0 for k in ("k1", "k2", "k3", "p1", "p2"))
    hdr = fits.Header()
    hdr["WCSAXES"] = 2
    hdr["CTYPE1"] = "RA---TAN-SIP" if distorts else "RA---TAN"
    hdr["CTYPE2"] = "DEC--TAN-SIP" if distorts else "DEC--TAN"
    hdr["CUNIT1"] = hdr["CUNIT2"] = "deg"
    hdr["RADESYS"] = ("ICRS", "axes of the star catalogue")
    hdr["CRVAL1"] = (ra0, "RA of the optical axis, deg")
    hdr["CRVAL2"] = (dec0, "Dec of the optical axis, deg")
    hdr["CRPIX1"] = (n * camera.cx + (n - 1) / 2 + 1.0, "principal point x, FITS pixels")
    hdr["CRPIX2"] = (n * camera.cy + (n - 1) / 2 + 1.0, "principal point y, FITS pixels")
    for i in range(2):
        for j in range(2):
            hdr[f"CD{i + 1}_{j + 1}"] = float(cd[i, j])
    hdr["IMAGEW"], hdr["IMAGEH"] = int(round(n * width)), int(round(n * height))
    residual = 0.0
    if distorts:
        fwd = _terms(sip_order, 2)
        m = _poly(u, w, fwd)
        a, *_ = np.linalg.lstsq(m, undist[:, 0] - u, rcond=None)
        b, *_ = np.linalg.lstsq(m, undist[:, 1] - w, rcond=None)
        residual = float(np.max(np.hypot(m @ a + u - undist[:, 0], m @ b + w - undist[:, 1])))
        inv = _terms(sip_order, 1)
        mi = _poly(undist[:, 0], undist[:, 1], inv)
        ap, *_ = np.linalg.lstsq(mi, u - undist[:, 0], rcond=None)
        bp, *_ = np.linalg.lstsq(mi, w - undist[:, 1], rcond=None)
        hdr["A_ORDER"] = hdr["B_ORDER"] = sip_order
        for (p, s), ca, cb in zip(fwd, a, b):
            hdr[f"A_{p}_{s}"], hdr[f"B_{p}_{s}"] = float(ca), float(cb)
        hdr["AP_ORDER"] = hdr["BP_ORDER"] = sip_order
        for (p, s), ca, cb in zip(inv, ap, bp):
            hdr[f"AP_{p}_{s}"], hdr[f"BP_{p}_{s}"] = float(ca), float(cb)
    hdr["COMMENT"] = "lodestar solve: TAN about the principal point" + \
        (f"; SIP order {sip_order} fitted to Brown-Conrady, max residual {residual:.3f} px"
         if distorts else "; pinhole camera, exact")
    return hdr, residual


def header_bytes(header):
    """A FITS file of the header alone (no data, as astrometry.net's ``.wcs`` files)."""
    from astropy.io import fits

    buf = io.BytesIO()
    fits.PrimaryHDU(header=header).writeto(buf)
    return buf.getvalue()
