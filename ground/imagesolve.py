"""Read a sky image (PNG, TIFF, FITS) into integer pixels, build its camera and detector
settings, and solve it with the golden detector and the flight firmware (``lodestar solve``).
Reading rules, settings and outputs: ``docs/image_solving.md``."""

import math
import time
import warnings

import numpy as np

from lodestar import contract as C
from lodestar.contract import stardb
from lodestar.firmware import centroids
from lodestar.firmware import status as S
from lodestar.firmware.camera import Camera
from lodestar.golden import DetectorConfig, detect_frame
from lodestar.ground import annotate, fovsearch, onboard, solve
from lodestar.ground.database import default_catalogue
from lodestar.sim import presets
from lodestar.sim.attitude import to_radec_roll
from lodestar.sim.catalogue import load

DEFAULT_KSIGMA = 5.0
"""Local threshold offset in units of the estimated pixel noise."""
DEFAULT_MIN_PIXELS = 3
"""Smallest blob kept by the detector: drops hot pixels and pairs."""
MIN_DISTINCT_VALUES = 32
"""Fewer distinct values than this never count as evidence of left-aligned data."""
MIN_SIZE_PX = 16
"""Smallest accepted image width and height, px."""
MAX_BIN = 16
"""Largest ``--bin`` factor."""
MAX_PIXELS = 16384 * 16384
"""Most pixels of an image that is decoded at all (about 1 GB of 32-bit pixels)."""
DATA_BITS_16 = tuple(sorted(set(C.SENSOR_PIXEL_BITS.values()) | {16}))
"""Widths right-aligned data in a 16-bit file are read as: the sensors' (10, 12) and 16."""
LUMA = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights of R, G, B."""

_MAGIC = ((b"\x89PNG\r\n\x1a\n", "PNG"), (b"II*\x00", "TIFF"), (b"MM\x00*", "TIFF"),
          (b"II+\x00", "TIFF"), (b"MM\x00+", "TIFF"), (b"SIMPLE  =", "FITS"))


class SkyImage:
    """A frame ready for the detector: ``frame`` (``uint16`` ``[y, x]``), ``pixel_bits``,
    ``format`` (``"PNG"``...), ``width``/``height`` of the file's image, ``bin`` (the frame is
    that image binned ``bin x bin``), ``notes`` (what was converted or assumed)."""

    def __init__(self, frame, pixel_bits, fmt, width, height, binning, notes):
        self.frame = frame
        self.pixel_bits = pixel_bits
        self.format = fmt
        self.width = width
        self.height = height
        self.bin = binning
        self.notes = notes

    def to_original(self, x, y):
        """Original image pixel of binned pixel ``(x, y)``."""
        n = self.bin
        return n * x + (n - 1) / 2, n * y + (n - 1) / 2


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------

def _sniff(path):
    with open(path, "rb") as fh:
        head = fh.read(64)
    if not head:
        raise ValueError(f"{path}: the file is empty")
    for magic, fmt in _MAGIC:
        if head.startswith(magic):
            return fmt, head
    raise ValueError(f"{path}: not a PNG, TIFF or FITS file (unrecognised first bytes)")


def check_size(width, height, binning):
    """Refuse, before its pixels are decoded, an image that even binned ``binning`` x
    ``binning`` is larger than the detector's frame (a small file may hold a huge image)."""
    if width * height > MAX_PIXELS:
        raise SizeError(f"the image is {width}x{height}: more than {MAX_PIXELS} pixels")
    if math.ceil(width / binning) > C.MAX_WIDTH or math.ceil(height / binning) > C.MAX_HEIGHT:
        need = max(math.ceil(width / C.MAX_WIDTH), math.ceil(height / C.MAX_HEIGHT))
        if need > MAX_BIN:
            raise SizeError(f"the image is {width}x{height}: too large even binned {MAX_BIN} x "
                            f"{MAX_BIN} (crop it)")
        raise SizeError(f"the image is {width}x{height}; the detector takes at most "
                        f"{C.MAX_WIDTH}x{C.MAX_HEIGHT}: use --bin {need} (or crop it)")


class SizeError(ValueError):
    """The image is too large for the detector (found from its header)."""


def _read_png(path, head, notes, binning):
    from PIL import Image

    depth, colour_type = head[24], head[25]      # IHDR: bit depth, colour type
    with Image.open(path) as im:
        check_size(im.size[0], im.size[1], binning)
        im.load()
        mode = im.mode
        if mode == "P":
            notes.append("palette image expanded to RGB")
            im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            mode = im.mode
        elif mode == "1":
            notes.append("1-bit image read as 8-bit")
            im = im.convert("L")
            mode = "L"
        data = np.asarray(im)
    if depth == 16 and colour_type in (2, 6):
        notes.append("16-bit colour PNG: Pillow reads it at 8 bits per channel")
    if mode in ("LA", "La", "PA"):
        data = data[..., 0]
        notes.append("alpha channel dropped")
    return data


def _read_tiff(path, notes, binning):
    import tifffile

    with tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        axes = series.axes
        if "X" in axes and "Y" in axes:
            check_size(series.shape[axes.index("X")], series.shape[axes.index("Y")], binning)
        data = series.asarray()
    if data.ndim == 3 and axes.startswith("S") and data.shape[0] in (3, 4):
        data = np.moveaxis(data, 0, -1)                 # planar colour -> samples last
        axes = axes[1:] + "S"
    if data.ndim >= 3 and not axes.endswith("S"):
        notes.append(f"{data.shape[0]} frames in the file ({axes}): the first is used")
        data = data[0]
        axes = axes[1:]
    if data.ndim == 3 and data.shape[-1] == 2:          # grey + alpha
        notes.append("alpha channel dropped")
        data = data[..., 0]
    return data


def _read_fits(path, notes, binning):
    from astropy.io import fits

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with fits.open(path, memmap=False) as hdus:
                hdu = next((h for h in hdus if h.header.get("NAXIS", 0) >= 2 and
                            h.header.get("NAXIS1") and h.header.get("NAXIS2")), None)
                if hdu is None:
                    raise ValueError("no image data (no HDU with 2 or more axes)")
                check_size(int(hdu.header["NAXIS1"]), int(hdu.header["NAXIS2"]), binning)
                if hdu.data is None:
                    raise ValueError("no image data (no HDU with 2 or more axes)")
                data = np.array(hdu.data)
        except SizeError:
            raise
        except Exception as exc:
            said = "; ".join(str(w.message) for w in caught)
            raise ValueError(f"{exc}" + (f" ({said})" if said else "")) from None
    notes.extend(f"FITS: {w.message}" for w in caught)
    if data.ndim == 3 and data.shape[0] == 3:
        data = np.moveaxis(data, 0, -1)
    elif data.ndim >= 3:
        notes.append(f"{data.shape[0]} planes in the cube: the first is used")
        data = data.reshape((-1,) + data.shape[-2:])[0]
    return data


def _fill_blanks(data, notes):
    """Float data with NaN or infinite pixels (blank in FITS, TIFF or any float image): those
    pixels become the median of the others, with a note."""
    if data.dtype.kind != "f" or np.all(np.isfinite(data)):
        return data
    bad = ~np.isfinite(data)
    if bad.all():
        raise ValueError("every pixel is blank (NaN or infinite)")
    notes.append(f"{int(bad.sum())} blank (NaN or infinite) pixels set to the median")
    return np.where(bad, np.median(data[~bad]), data)


def _luminance(data, notes):
    if data.ndim == 2:
        return data
    if data.ndim != 3 or data.shape[-1] not in (3, 4):
        raise ValueError(f"unsupported image shape {data.shape}")
    if data.shape[-1] == 4:
        notes.append("alpha channel dropped")
    notes.append("colour image converted to luminance 0.2126 R + 0.7152 G + 0.0722 B")
    rgb = data[..., :3].astype(np.float64)
    lum = rgb @ np.asarray(LUMA)
    if data.dtype.kind in "ui":
        return np.rint(lum).astype(data.dtype)
    return lum


def _to_integers(data, notes):
    """``(uint16 array, container bits)``: 8 for uint8 data, else 16."""
    if data.dtype == np.uint8 or data.dtype == np.bool_:
        return data.astype(np.uint16), 8
    if data.dtype.kind in "ui":
        lo, hi = int(data.min()), int(data.max())
        if lo >= 0 and hi <= 0xFFFF:
            return data.astype(np.uint16), 16
    elif data.dtype.kind == "f":
        lo, hi = float(data.min()), float(data.max())
        if lo >= 0 and hi <= 0xFFFF and np.all(data == np.rint(data)):
            return data.astype(np.uint16), 16
    else:
        raise ValueError(f"unsupported pixel type {data.dtype}")
    notes.append(f"{data.dtype} data ({lo:g} .. {hi:g}) scaled linearly onto 0 .. 65535")
    scaled = (data.astype(np.float64) - lo) * (65535.0 / (hi - lo))
    return np.rint(scaled).astype(np.uint16), 16


def _significant_bits(frame, container, bits, notes):
    """``(frame, pixel_bits)`` by the rule of the module docstring."""
    if container == 8:
        if bits not in (None, 8):
            raise ValueError(f"--bits {bits}: the file holds 8-bit data")
        return frame, 8
    hi = int(frame.max())
    if bits is not None:
        if hi <= C.full_scale(bits):
            return frame, bits
        shift = 16 - bits
        if not np.any(frame & ((1 << shift) - 1)):
            notes.append(f"{bits}-bit data left-aligned in 16 bits: shifted down by {shift}")
            return frame >> shift, bits
        raise ValueError(f"--bits {bits}: values up to {hi} neither fit {bits} bits nor are "
                         f"left-aligned {bits}-bit data")
    combined = int(np.bitwise_or.reduce(frame, axis=None))
    shift = (combined & -combined).bit_length() - 1 if combined else 0
    if shift >= 1 and len(np.unique(frame[::7, ::7])) >= MIN_DISTINCT_VALUES:
        width = 16 - shift
        pixel_bits = min(b for b in C.PIXEL_BITS if b >= width)
        notes.append(f"the lowest {shift} bits of every pixel are zero: {width}-bit data "
                     f"left-aligned in 16 bits, shifted down (--bits overrides)")
        return frame >> shift, pixel_bits
    pixel_bits = min(b for b in DATA_BITS_16 if hi <= C.full_scale(b))
    if pixel_bits < 16:
        widths = ", ".join(str(b) for b in DATA_BITS_16)
        notes.append(f"16-bit file, largest value {hi}: read as {pixel_bits}-bit data (the "
                     f"smallest of {widths} bits that holds it; --bits overrides)")
    return frame, pixel_bits


def _bin(frame, n, notes):
    h, w = frame.shape
    hb, wb = h // n, w // n
    if hb < 1 or wb < 1:
        raise ValueError(f"--bin {n} leaves no pixel of a {w}x{h} image")
    if w % n or h % n:
        notes.append(f"--bin {n}: the last {w % n} columns and {h % n} rows dropped")
    blocks = frame[:hb * n, :wb * n].astype(np.uint32).reshape(hb, n, wb, n)
    return (blocks.sum(axis=(1, 3)) // (n * n)).astype(np.uint16)


def read_image(path, bits=None, binning=1):
    """Read ``path`` into a :class:`SkyImage` (rules in the module docstring).  ``bits``:
    significant bits of 16-bit data (None: detected); ``binning``: ``N`` of ``--bin``.
    Raises ``ValueError`` (or ``OSError`` for a file that cannot be opened) with a message
    naming the file and the problem."""
    if bits is not None and bits not in C.PIXEL_BITS:
        raise ValueError(f"--bits must be one of {C.PIXEL_BITS}, got {bits}")
    if not isinstance(binning, int) or not 1 <= binning <= MAX_BIN:
        raise ValueError(f"--bin must be an int in 1..{MAX_BIN}, got {binning!r}")
    fmt, head = _sniff(path)
    notes = []
    try:
        if fmt == "PNG":
            data = _read_png(path, head, notes, binning)
        elif fmt == "TIFF":
            data = _read_tiff(path, notes, binning)
        else:
            data = _read_fits(path, notes, binning)
    except SizeError as exc:
        raise ValueError(f"{path}: {exc}") from None
    except Exception as exc:    # every decoder error (truncated, corrupt, unsupported) alike
        raise ValueError(f"{path}: cannot read the {fmt} image: {exc}") from None
    try:
        data = _fill_blanks(_luminance(np.asarray(data), notes), notes)
        if data.ndim != 2:
            raise ValueError(f"unsupported image shape {data.shape}")
        height, width = data.shape
        if width < MIN_SIZE_PX or height < MIN_SIZE_PX:
            raise ValueError(f"the image is {width}x{height}: too small for a star field (at "
                             f"least {MIN_SIZE_PX}x{MIN_SIZE_PX})")
        if data.min() == data.max():
            raise ValueError(f"every pixel is {data.flat[0]}: a blank image")
        frame, container = _to_integers(data, notes)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    frame, pixel_bits = _significant_bits(frame, container, bits, notes)
    if binning > 1:
        frame = _bin(frame, binning, notes)
    hb, wb = frame.shape
    if wb > C.MAX_WIDTH or hb > C.MAX_HEIGHT:
        need = max(math.ceil(width / C.MAX_WIDTH), math.ceil(height / C.MAX_HEIGHT))
        raise ValueError(f"{path}: the image is {width}x{height}; the detector takes at most "
                         f"{C.MAX_WIDTH}x{C.MAX_HEIGHT}: use --bin {need} (or crop it)")
    return SkyImage(np.ascontiguousarray(frame), pixel_bits, fmt, width, height, binning, notes)


# --------------------------------------------------------------------------------------
# Camera and detector
# --------------------------------------------------------------------------------------

def image_camera(image, preset=None, fov_deg=None, distortion=None, camera=None,
                 fov_error=None):
    """``(firmware Camera of the detector's frame, description)`` for ``image``: the preset's
    camera, or the ``fov_deg`` pinhole with ``distortion`` ``(k1, k2, k3, p1, p2)``, or
    ``camera`` (a firmware Camera of the whole image, e.g. a camera file's), scaled to the
    binned frame; ``(None, description)`` when the FOV is to be searched (:func:`fov_band`:
    no camera option and an image not of the default preset's size, or ``fov_error``).
    Raises ``ValueError`` for an absurd FOV, a distortion that cannot be inverted over the
    frame, a size that differs from the preset's or the camera's, or conflicting options."""

    if camera is not None:
        if (preset is not None or fov_deg is not None or distortion is not None or
                fov_error is not None):
            raise ValueError("give one camera: --camera, --preset or --fov")
        if (camera.width, camera.height) != (image.width, image.height):
            raise ValueError(f"the image is {image.width}x{image.height}, the camera "
                             f"{camera.width}x{camera.height}")
        full = (camera.fx, camera.fy, camera.cx, camera.cy,
                {k: getattr(camera, k) for k in ("k1", "k2", "k3", "p1", "p2")})
        what = "camera file"
    elif fov_error is not None or (fov_deg is None and preset is None and
                                   not _default_preset_fits(image)):
        lo, hi = fov_band(fov_deg, fov_error, preset, distortion)
        return None, f"FOV searched in {lo:g} .. {hi:g} deg"
    elif fov_deg is not None:
        if preset is not None:
            raise ValueError("give --preset or --fov, not both")
        lo, hi = stardb.FOV_RANGE_DEG
        if not (math.isfinite(fov_deg) and lo <= fov_deg <= hi):
            raise ValueError(f"--fov {fov_deg:g} is absurd: the horizontal field of view must "
                             f"be in {lo:g} .. {hi:g} degrees")
        keys = ("k1", "k2", "k3", "p1", "p2")
        dist = dict(zip(keys, distortion)) if distortion is not None else {}
        f = (image.width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
        full = (f, f, (image.width - 1) / 2, (image.height - 1) / 2, dist)
        what = f"--fov {fov_deg:g} deg" + (" with distortion" if dist else "")
    else:
        if distortion is not None:
            raise ValueError("--distortion needs --fov (a preset has its own distortion)")
        name = preset or presets.DEFAULT_PRESET
        cam = presets.load_preset(name)
        if (cam.width, cam.height) != (image.width, image.height):
            raise ValueError(f"the image is {image.width}x{image.height}, the {name} camera "
                             f"{cam.width}x{cam.height}")
        fw = onboard.firmware_camera(cam)
        full = (fw.fx, fw.fy, fw.cx, fw.cy,
                {"k1": fw.k1, "k2": fw.k2, "k3": fw.k3, "p1": fw.p1, "p2": fw.p2})
        what = f"preset {name}"
    # the camera of the detector's (binned) frame: the original's scaled, so that an image
    # wider than the detector solves with --bin
    fx, fy, cx, cy, dist = full
    n = image.bin
    camera = Camera(image.frame.shape[1], image.frame.shape[0], fx / n, fy / n,
                    (cx + 0.5) / n - 0.5, (cy + 0.5) / n - 0.5, **dist)
    return camera, what + (f", binned {n}x{n}" if n > 1 else "")


def _default_preset_fits(image):
    cam = presets.load_preset(presets.DEFAULT_PRESET)
    return (cam.width, cam.height) == (image.width, image.height)


def fov_band(fov_deg=None, fov_error=None, preset=None, distortion=None):
    """``(lo, hi)`` horizontal FOVs (deg) a blind solve searches: ``fov_deg +- fov_error``,
    or :data:`lodestar.ground.fovsearch.FOV_RANGE_DEG` without a FOV; the part the quad
    index reaches (:func:`lodestar.ground.fovsearch.reach_deg`).  Raises ``ValueError`` for
    a band the index does not reach, a bad ``fov_error``, or a preset or distortion with it
    (the search fits a pinhole)."""
    if preset is not None or distortion is not None:
        raise ValueError("--fov-error and the FOV search fit a pinhole: not with --preset or "
                         "--distortion")
    if fov_deg is None:
        if fov_error is not None:
            raise ValueError("--fov-error needs --fov")
        return fovsearch.FOV_RANGE_DEG
    if not (math.isfinite(fov_error) and 0 < fov_error < fov_deg):
        raise ValueError(f"--fov-error must be a number of degrees in (0, --fov), got "
                         f"{fov_error:g}")
    reach = fovsearch.reach_deg()
    lo, hi = max(fov_deg - fov_error, reach[0]), min(fov_deg + fov_error, reach[1])
    if lo > hi:
        raise ValueError(f"--fov {fov_deg:g} --fov-error {fov_error:g}: the FOV search reaches "
                         f"{reach[0]:.1f} .. {reach[1]:.1f} deg")
    return lo, hi


def noise_sigma(frame):
    """Pixel noise (ADU) of a frame: ``median |p[y, x+1] - p[y, x]| / (0.6745 sqrt 2)``, the
    Gaussian standard deviation behind the median absolute difference of row neighbours
    (smooth gradients and sparse stars barely move the median).  Every 4th row is used."""
    rows = frame[::4].astype(np.int32)
    diff = np.abs(np.diff(rows, axis=1))
    return float(np.median(diff)) / (0.6745 * math.sqrt(2.0))


def detector_config(image, ksigma=DEFAULT_KSIGMA, min_pixels=DEFAULT_MIN_PIXELS):
    """``(DetectorConfig, sigma)`` for a :class:`SkyImage`: local mode as the module
    docstring says (window ``min(128, the largest power of two below the width)``)."""

    if not (math.isfinite(ksigma) and ksigma > 0):
        raise ValueError(f"--ksigma must be a positive number, got {ksigma}")
    frame = image.frame
    sigma = noise_sigma(frame)
    fs = C.full_scale(image.pixel_bits)
    offset = min(fs, max(1, math.ceil(ksigma * sigma)))
    log2_window = max(C.LOCAL_LOG2_WINDOW_MIN,
                      min(C.LOCAL_LOG2_WINDOW_MAX, (frame.shape[1] - 1).bit_length() - 1))
    cfg = DetectorConfig(width=frame.shape[1], height=frame.shape[0],
                         pixel_bits=image.pixel_bits, threshold_mode="local",
                         local_log2_window=log2_window, local_offset=offset,
                         min_pixels=min_pixels, min_sum=0,
                         record_capacity=C.MAX_RECORD_CAPACITY)
    return cfg, sigma


# --------------------------------------------------------------------------------------
# Solving
# --------------------------------------------------------------------------------------

def fits_date_obs(path):
    """The ``DATE-OBS`` of a FITS file's first header that has one (the observation time
    for the aberration correction), or None (another format, no such keyword)."""
    if _sniff(path)[0] != "FITS":
        return None
    from astropy.io import fits
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with fits.open(path, memmap=False) as hdus:
            for hdu in hdus:
                value = hdu.header.get("DATE-OBS")
                if value:
                    return str(value)
    return None


def frame_timing(image, what, exposure_s=None, row_time_s=None):
    """``(exposure_s, row_time_s)`` of the detector's frame: the given ones, else the preset's
    when the camera is a preset's (``what`` of :func:`image_camera`), else an unknown
    exposure (None) and one instant for every row (0: the rate is not fitted, the attitude
    holds at mid-exposure).  A binned frame's row spans ``image.bin`` rows."""
    preset = what.split()[1].rstrip(",") if what.startswith("preset ") else None
    cam = presets.load_preset(preset) if preset is not None else None
    if exposure_s is None and cam is not None:
        exposure_s = cam.exposure_s
    if row_time_s is None:
        row_time_s = cam.row_time_s if cam is not None and cam.shutter == "rolling" else 0.0
    return exposure_s, row_time_s * image.bin


def solve_image(image, camera, max_mag=None, tolerance_px=None,
                ksigma=DEFAULT_KSIGMA, min_pixels=DEFAULT_MIN_PIXELS, log=None, fov_band=None,
                velocity_km_s=None, motion=(None, None, 0.0), refine=None):
    """Detect and solve a :class:`SkyImage` with a firmware ``camera`` of its frame (None:
    the FOV is searched over ``fov_band``, deg, :func:`blind_camera`):
    ``(report dict, DetectionResult, pipeline Result, camera)`` (report fields in the module
    docstring).  ``max_mag``: every star to that V in the database; None: the stars per
    field of :data:`lodestar.ground.solve.DEFAULT_DENSITY` from the whole Hipparcos.
    ``log``: text stream for the database notes (None: silent).  ``velocity_km_s``: the
    observer's (ICRS, :func:`lodestar.ground.solve.observer_velocity_km_s`) for the aberration
    correction, or None.  ``motion``: ``(omega, exposure_s, row_time_s)``, the body rate
    (rad/s, camera frame; None: fitted from the frame) and the frame's timing
    (:func:`frame_timing`).  ``refine``: run after the first solve when the camera is
    unknown, ``refine(image, det, camera, res, (db, db_path), ctx)`` with ``ctx`` the
    ``(max_mag, tolerance_px, log, timings, velocity_km_s, motion)`` of :func:`solve_at`,
    returning ``(camera, res, db, db_path, fit)`` (:func:`lodestar.ground.lensfit.refine`:
    the lens fitted to the matched stars; ``fit.as_dict()`` is the report's ``lens``), or
    None."""

    lo, hi = solve.MAG_RANGE
    if max_mag is not None and not (math.isfinite(max_mag) and lo < max_mag <= hi):
        raise ValueError(f"--mag must be a finite V magnitude in ({lo:g}, {hi:g}], got "
                         f"{max_mag}")
    timings = {}
    cfg, sigma = detector_config(image, ksigma, min_pixels)
    t = time.perf_counter()
    det = detect_frame(image.frame, cfg)
    timings["detect"] = (time.perf_counter() - t) * 1e3
    search = None
    if camera is None:
        t = time.perf_counter()
        camera, search = blind_camera(image, det, fov_band or fovsearch.FOV_RANGE_DEG,
                                      tolerance_px, log)
        timings["fov_search"] = (time.perf_counter() - t) * 1e3
    res = db = db_path = None
    if camera is not None:
        for attempt in range(2 if search else 1):   # the estimate, then the fitted scale
            db, db_path, res, stage = solve_at(image, det, camera, max_mag, tolerance_px,
                                                log, timings, blind=search is not None,
                                                velocity_km_s=velocity_km_s, motion=motion)
            if search is None or attempt or not (res.ok or res.status == S.IMPRECISE):
                break
            idx = [(x, y, hip) for _i, x, y, hip in res.matches]
            f_new = solve.refit_focal([(x, y) for x, y, _h in idx],
                                             [h for _x, _y, h in idx], camera.width,
                                             camera.height, camera.fx)
            if abs(f_new / camera.fx - 1) < 1e-6:
                break
            camera = _pinhole(camera.width, camera.height, f_new)
    lens = None
    if camera is not None and refine is not None:
        camera, res, db, db_path, lens = refine(
            image, det, camera, res, (db, db_path),
            (max_mag, tolerance_px, log, timings, velocity_km_s, motion))
    if search is not None and camera is not None:
        search["fitted_deg"] = solve.camera_fov_deg(camera)[0]
    fov_h, fov_v = solve.camera_fov_deg(camera) if camera is not None else (None, None)
    report = {
        "status": res.status_name if res is not None else "NO_MATCH",
        "reason": res.reason if res is not None else
        (f"no field of view in {search['range_deg'][0]:g} .. {search['range_deg'][1]:g} deg "
         f"verified ({search['candidates']} candidate quads)"),
        "ra_deg": None, "dec_deg": None,
        "roll_deg": None, "q": None, "t_epoch_s": None, "rate_deg_s": None,
        "sigma_rate_deg_s": None, "fov_deg": fov_h, "fov_vertical_deg": fov_v,
        "pixel_scale_arcsec": None if camera is None else
        solve.ARCSEC_PER_RAD / math.sqrt(camera.fx * camera.fy) / image.bin,
        "fov_search": search,
        "lens": None if lens is None else lens.as_dict(),
        "matches": [], "sigma_cross_arcsec": None, "sigma_roll_arcsec": None,
        "n_stars": res.n_stars if res is not None else 0,
        "image": {"format": image.format, "width": image.width, "height": image.height,
                  "pixel_bits": image.pixel_bits, "bin": image.bin, "notes": image.notes},
        "detector": {"mode": "local", "window_px": 1 << cfg.local_log2_window,
                     "local_offset": cfg.local_offset, "noise_sigma_adu": sigma,
                     "min_pixels": cfg.min_pixels, "records": len(det.blobs),
                     "n_filtered": det.n_filtered, "dropped": det.dropped},
        "database": None if db_path is None else str(db_path),
        "mag_limit": None if db is None else float(db.mag_limit),
        "velocity_km_s": velocity_km_s,
        "timings_ms": timings,
    }
    if res is not None and res.ok:
        cat = default_catalogue(max_mag)
        ra, dec, roll = to_radec_roll(np.asarray(res.q))
        report.update(ra_deg=float(ra), dec_deg=float(dec), roll_deg=float(roll),
                      q=[float(v) for v in res.q], t_epoch_s=res.t_epoch_s,
                      rate_deg_s=_degrees(res.rate_rad_s),
                      sigma_rate_deg_s=_degrees(res.sigma_rate_rad_s),
                      sigma_cross_arcsec=res.sigma_cross_arcsec,
                      sigma_roll_arcsec=res.sigma_roll_arcsec)
        for _index, x, y, hip in res.matches:
            xo, yo = image.to_original(x, y)
            report["matches"].append({"x": xo, "y": yo, "hip": hip, "name": cat.name(hip),
                                      "vmag": float(cat.vmag[cat.by_hip(hip)])})
    elif not det.blobs:
        report["reason"] = (f"no stars found: nothing above the local threshold (mean of "
                            f"{1 << cfg.local_log2_window} row neighbours + "
                            f"{cfg.local_offset} ADU)")
    return report, det, res, camera


def _degrees(rate):
    """A rate (rad/s) in deg/s as a list, or None."""
    return None if rate is None else [math.degrees(float(w)) for w in rate]


def _pinhole(width, height, f_px):
    return Camera(width, height, f_px, f_px, (width - 1) / 2, (height - 1) / 2)


def solve_at(image, det, camera, max_mag, tolerance_px, log, timings, blind,
              velocity_km_s=None, motion=(None, None, 0.0), database=None):
    """One flight solve of ``det`` through ``camera`` (a blind solve's database is that of
    the FOV grid of :func:`lodestar.ground.solve.database_fov`; ``database``: ``(db,
    db_path)`` given), aberration corrected for ``velocity_km_s`` when given."""
    if database is not None:
        db, db_path = database
    else:
        db_camera = camera
        if blind:
            fov_h = solve.database_fov(solve.camera_fov_deg(camera)[0])
            db_camera = _pinhole(camera.width, camera.height,
                                 fovsearch.f_of_fov(camera.width, fov_h))
        t = time.perf_counter()
        db, db_path = onboard.star_database(
            db_camera, max_mag, log=log,
            density=solve.DEFAULT_DENSITY if max_mag is None else None)
        timings["database"] = timings.get("database", 0.0) + (time.perf_counter() - t) * 1e3
    omega, exposure_s, row_time_s = motion
    _data, res, stage = onboard.process(det, camera, db, omega=omega, exposure_s=exposure_s,
                                        row_time_s=row_time_s, tolerance_px=tolerance_px,
                                        max_work=solve.GROUND_MAX_WORK,
                                        velocity_km_s=velocity_km_s)
    for key in ("packet", "solve"):
        timings[key] = timings.get(key, 0.0) + stage[key]
    return db, db_path, res, stage


def blind_camera(image, det, band, tolerance_px=None, log=None):
    """``(camera or None, search dict)``: the centred pinhole of the detector's frame whose
    focal length the quad search (:func:`lodestar.ground.fovsearch.search_fov`) finds from
    the firmware's centroids of ``det`` (brightest first, border stars dropped) with the
    horizontal FOV in ``band`` (deg); ``log``: where the index build is said."""
    w, h = image.frame.shape[1], image.frame.shape[0]
    stars, _rejected = centroids.extract(det.blobs, max_stars=fovsearch.IMAGE_STARS,
                                           border=(w, h))
    xy = np.array([(s.x, s.y) for s in stars], dtype=np.float64).reshape(-1, 2)
    est = fovsearch.search_fov(xy, w, h, band, tolerance_px or 2.0, log=log)
    search = {"range_deg": [float(band[0]), float(band[1])], "candidates": est.candidates,
              "estimate_deg": est.fov_deg, "level_deg": est.level_deg,
              "quad_matches": est.n_matches}
    if est.f_px is None:
        return None, search
    return _pinhole(w, h, est.f_px), search


def write_annotated(path, image, camera, det, res, report, max_mag):
    """The annotated picture: records, matches and, with a solution, the catalogue stars
    to ``max_mag`` (None: the database's faintest star, at most the shipped V 8.03)."""
    labels, markers = [], {}
    if max_mag is None:
        max_mag = min(report["mag_limit"] or math.inf, float(load().vmag.max()))
    legend = [f"lodestar solve: {report['image']['format']} {image.width}x{image.height}, "
              f"{image.pixel_bits}-bit" + (f", binned {image.bin}x{image.bin}" if image.bin > 1
                                           else "") +
              ("" if report["fov_deg"] is None else f", FOV {report['fov_deg']:.3f} deg") +
              f", {len(det.blobs)} records (yellow boxes)"]
    if res.ok:
        markers["solution"] = [(x, y) for x, y, _h, _v in
                               annotate.predict_pixels(res.q, camera, max_mag)]
        cat_names = {m["hip"]: m["name"] for m in report["matches"]}
        for _index, x, y, hip in res.matches:
            name = cat_names.get(hip)
            labels.append((x, y, f"HIP {hip}" + (f" {name}" if name else ""), None))
        legend.append(f"OK: RA {report['ra_deg']:.4f} Dec {report['dec_deg']:+.4f} roll "
                      f"{report['roll_deg']:+.4f} deg, {len(res.matches)} stars (green)")
        legend.append(f"magenta crosses: catalogue stars V <= {max_mag:g} predicted from the "
                      "solution")
    else:
        legend.append(f"{report['status']}: {report['reason']}")
    annotate.save_annotated(path, image.frame, records=det.blobs, labels=labels,
                            markers=markers, legend=legend,
                            identified=[index for index, _x, _y, _h in res.matches])


def format_report(path, r, camera_what):
    """The report as text for people."""
    im, d = r["image"], r["detector"]
    lines = [f"{path}: {im['format']} {im['width']}x{im['height']}, {im['pixel_bits']}-bit"
             + (f", binned {im['bin']}x{im['bin']}" if im["bin"] > 1 else "") +
             f"; camera {camera_what}" + ("" if r["fov_deg"] is None else
                                          f": FOV {r['fov_deg']:.3f} x "
                                          f"{r['fov_vertical_deg']:.3f} deg, "
                                          f"{r['pixel_scale_arcsec']:.3f}\"/px"),
             f"  detector   local mode, {d['window_px']}-px window, offset "
             f"{d['local_offset']} ADU (noise {d['noise_sigma_adu']:.2f} ADU), min "
             f"{d['min_pixels']} px: {d['records']} records"]
    if r["status"] == "OK":
        lines.append(f"  solution   RA {r['ra_deg']:.5f}  Dec {r['dec_deg']:+.5f}  roll "
                     f"{r['roll_deg']:+.5f} deg; 1-sigma cross-boresight "
                     f"{r['sigma_cross_arcsec']:.2f}\" per axis, roll "
                     f"{r['sigma_roll_arcsec']:.2f}\"; {len(r['matches'])} stars matched")
        lines.append(f"  {'x':>9} {'y':>9} {'HIP':>7}  {'name':<16} {'V':>5}")
        for m in r["matches"]:
            lines.append(f"  {m['x']:>9.2f} {m['y']:>9.2f} {m['hip']:>7}  "
                         f"{m['name'] or '':<16} {m['vmag']:>5.2f}")
    if r.get("fov_search") and r["fov_search"].get("fitted_deg"):
        fs = r["fov_search"]
        lines.append(f"  FOV        fitted {fs['fitted_deg']:.4f} deg (searched "
                     f"{fs['range_deg'][0]:g} .. {fs['range_deg'][1]:g} deg, "
                     f"{fs['candidates']} candidate quads, estimate {fs['estimate_deg']:.4f})")
    if r.get("lens"):
        ln = r["lens"]
        lines.append(f"  lens       fitted from {ln['n_stars']} stars: k1 {ln['k1']:+.4f} +- "
                     f"{ln['sigma_k1']:.4f}" + ("" if ln["k2"] is None else
                                                 f", k2 {ln['k2']:+.4f} +- {ln['sigma_k2']:.4f}")
                     + f", f {ln['f_px']:.2f} px, fy/fx {ln['aspect']:.5f}; sigma x"
                     f"{ln['sigma_inflation'][0]:.2f} across, x{ln['sigma_inflation'][1]:.2f} "
                     f"in roll")
    tm = r["timings_ms"]
    lines.append("  timings    ms: " + ", ".join(f"{k} {v:.1f}" for k, v in tm.items()))
    lines.append(f"  status     {r['status']}" +
                 ("" if r["status"] == "OK" else f": not solved ({r['reason']})"))
    return "\n".join(lines)
