"""Detection results, field positions and hypothesis strategies shared by the ground and
flight packet-codec tests."""

import numpy as np
from hypothesis import strategies as st

from lodestar import contract as C
from lodestar.contract import DetectionResult
from lodestar.golden import Detector, DetectorConfig

HEADER_POS = {name: (offset, bits) for name, offset, bits in C.field_offsets(C.HEADER_FIELDS)}
"""``{name: (bit offset, bits)}`` of the header fields, from the packet start."""
RECORD_POS = {name: (offset, bits) for name, offset, bits in C.field_offsets(C.RECORD_FIELDS)}
"""``{name: (bit offset, bits)}`` of the record fields, from the record start."""


def base_result():
    """A valid 64x48 12-bit frame with 3 records, one dropped record and one filtered blob.

    Record 1 has the bounding box x 10..11, y 20..21 (area 4), n=4, nsat=1, peak at full
    scale; the semantic tests corrupt one field at a time.
    """
    fs = C.full_scale(12)
    blobs = [
        C.BlobRecord(n=1, nsat=0, s0=100, sx=300, sy=200, sxx=900, syy=400, sxy=600,
                     xmin=3, xmax=3, ymin=2, ymax=2, peak=240, flags=0),
        C.BlobRecord(n=4, nsat=1, s0=9000, sx=94500, sy=184500, sxx=992250, syy=3782250,
                     sxy=1937250, xmin=10, xmax=11, ymin=20, ymax=21, peak=fs, flags=0),
        C.BlobRecord(n=3, nsat=0, s0=500, sx=30500, sy=23500, sxx=1860500, syy=1104500,
                     sxy=1433500, xmin=60, xmax=62, ymin=47, ymax=47, peak=400, flags=0),
    ]
    return DetectionResult(blobs=blobs, mode=C.MODE_GLOBAL, threshold=200, background=40,
                           n_blobs=5, n_filtered=1, dropped_records=1, dropped_labels=0,
                           flags=C.FRAME_RECORD_OVERFLOW, frame_counter=7, width=64, height=48,
                           pixel_bits=12)


def spot_frame(rng, cfg, n_spots):
    """Noise below the threshold plus ``n_spots`` bright 1..3 px squares (some at full scale)."""
    fs = C.full_scale(cfg.pixel_bits)
    frame = rng.integers(0, max(cfg.threshold // 2, 1), (cfg.height, cfg.width))
    for _ in range(n_spots):
        size = int(rng.integers(1, 4))
        y, x = int(rng.integers(0, cfg.height)), int(rng.integers(0, cfg.width))
        frame[y:y + size, x:x + size] = rng.integers(cfg.threshold + 1, fs + 1)
    frame[rng.integers(0, cfg.height), rng.integers(0, cfg.width)] = fs
    return frame.astype(np.uint16)


CONFIGS = [
    dict(width=24, height=16, pixel_bits=8, threshold=100, record_capacity=2),
    dict(width=24, height=16, pixel_bits=10, threshold_mode="global", threshold=300,
         ksigma=1.5, min_pixels=2),
    dict(width=32, height=12, pixel_bits=12, threshold_mode="local", local_log2_window=3,
         local_offset=600, threshold=1000, record_capacity=3),
    dict(width=20, height=20, pixel_bits=16, threshold=20000, label_capacity=1,
         record_capacity=4),
    dict(width=24, height=16, pixel_bits=12, threshold=1500, min_sum=5000, max_pixels=6,
         record_capacity=0),
]
"""Configurations covering every mode, pixel width and capacity overflow."""


def spot_results(seed):
    """Golden results of seeded spot frames: 3 frames per configuration (global mode learns
    from the previous frame)."""
    rng = np.random.default_rng(seed)
    results = []
    for kwargs in CONFIGS:
        detector = Detector(DetectorConfig(**kwargs))
        for _ in range(3):
            results.append(detector.process(spot_frame(rng, detector.cfg, 12)))
    return results


def field_max(fields, name):
    """Largest value of field ``name`` of ``(name, bits)`` fields."""
    return (1 << dict(fields)[name]) - 1


def field_span(name, record=None):
    """``(bit_offset, bits)`` from the packet start of a header field (``record=None``) or of
    field ``name`` of record number ``record``."""
    if record is None:
        return HEADER_POS[name]
    offset, bits = RECORD_POS[name]
    return offset + 8 * (C.HEADER_BYTES + record * C.RECORD_BYTES), bits


@st.composite
def records(draw, width, height, pixel_bits):
    """A valid ``BlobRecord`` inside a ``width x height`` frame of ``pixel_bits`` pixels."""
    xmin = draw(st.integers(0, width - 1))
    xmax = draw(st.integers(xmin, width - 1))
    ymin = draw(st.integers(0, height - 1))
    ymax = draw(st.integers(ymin, height - 1))
    n = draw(st.integers(1, (xmax - xmin + 1) * (ymax - ymin + 1)))
    limits = C.moment_max(pixel_bits)
    moments = [draw(st.integers(0, limits[name])) for name in C.MOMENTS]
    flags = draw(st.integers(0, C.BLOB_FLAGS_DEFINED)) & C.BLOB_FLAGS_DEFINED
    if flags & C.BLOB_MOMENTS_SATURATED:       # a saturated blob has a moment at its limit
        k = draw(st.integers(0, len(C.MOMENTS) - 1))
        moments[k] = limits[C.MOMENTS[k]]
    nsat = draw(st.integers(0, n))
    fs = C.full_scale(pixel_bits)
    peak = fs if nsat else draw(st.integers(0, fs))
    return C.BlobRecord(n=n, nsat=nsat, xmin=xmin, xmax=xmax, ymin=ymin, ymax=ymax, peak=peak,
                        flags=flags, **dict(zip(C.MOMENTS, moments)))


@st.composite
def results(draw, max_records=6):
    """A valid ``DetectionResult`` with random in-range header fields and records."""
    pixel_bits = draw(st.sampled_from(C.PIXEL_BITS))
    width = draw(st.integers(1, C.MAX_WIDTH))
    height = draw(st.integers(1, C.MAX_HEIGHT))
    blobs = draw(st.lists(records(width, height, pixel_bits), max_size=max_records))
    share = (field_max(C.HEADER_FIELDS, "n_blobs") - len(blobs)) // 2
    n_filtered = draw(st.integers(0, share))
    dropped_records = draw(st.integers(0, share))
    dropped_labels = draw(st.integers(0, field_max(C.HEADER_FIELDS, "dropped_labels")))
    overflow = C.FRAME_RECORD_OVERFLOW | C.FRAME_LABEL_OVERFLOW
    flags = draw(st.integers(0, C.FRAME_FLAGS_DEFINED)) & C.FRAME_FLAGS_DEFINED & ~overflow
    flags |= C.FRAME_RECORD_OVERFLOW if dropped_records else 0
    flags |= C.FRAME_LABEL_OVERFLOW if dropped_labels else 0
    fs = C.full_scale(pixel_bits)
    return DetectionResult(
        blobs=blobs, mode=draw(st.integers(0, len(C.MODE_NAMES) - 1)),
        threshold=draw(st.integers(0, fs)), background=draw(st.integers(0, fs)),
        n_blobs=len(blobs) + n_filtered + dropped_records, n_filtered=n_filtered,
        dropped_records=dropped_records, dropped_labels=dropped_labels, flags=flags,
        frame_counter=draw(st.integers(0, field_max(C.HEADER_FIELDS, "frame_counter"))),
        width=width, height=height, pixel_bits=pixel_bits)
