"""Star-identification database layout: one little-endian binary image that the ground
builder (``lodestar.ground.database``) writes and the flight reader
(``lodestar.firmware.database``) reads by offset.  The layout is specified in
``docs/stardb.md``; every value of it is here.  MicroPython-safe: the values the tables
below are made of are ``const()``, so MicroPython folds the tables into constants that a
frozen image keeps in flash."""

try:
    from micropython import const
except ImportError:         # CPython
    def const(value):
        return value

MAGIC = b"LSDB"
VERSION = 1
HEADER_SIZE = 160

FOV_RANGE_DEG = (1.0, 90.0)
"""Horizontal fields of view (deg, edge to edge) a database is built for and a solve takes:
the one range every ground tool checks (``lodestar.ground.database.check_fov``), so no
database is written for a field no solve accepts."""
MAX_STARS = 65535
"""Most stars of an image: star indices are 16-bit (``PAIR_FORMAT``, ``CELL_FORMAT``)."""

# Fixed header fields before the section directory (88 bytes, little endian).
HEADER_FORMAT = "<4sHHIIHHfffffIIIfffIffHHff"
HEADER_FIELDS = ("magic", "version", "header_size", "image_size", "payload_crc",
                 "methods", "star_record_size", "fov_h", "fov_v", "fov_diag", "mag_limit",
                 "epoch", "n_stars", "n_pattern_stars", "n_pairs", "pair_min_angle",
                 "pair_max_angle", "key_step", "kv_bins", "kv_m", "kv_q", "cells_per_face",
                 "pattern_per_region", "cell_radius", "pattern_radius")
DIRECTORY_OFFSET = 88        # N_SECTIONS entries of "<II" (offset, length) in bytes
N_SECTIONS = 8
RESERVED_OFFSET = 152        # "<I", zero
HEADER_CRC_OFFSET = 156      # "<I": CRC-32 of header bytes [0, 156)
SECTION_ALIGN = 4

# Section ids (index into the directory).  Length 0 = absent.
SEC_STARS = const(0)      # n_stars records of STAR_FORMAT
SEC_CELLS = const(1)      # (6 * cells_per_face**2 + 1) x "<H": first star of each cell
SEC_PAIRS = const(2)      # n_pairs records of PAIR_FORMAT, sorted by (key, a, b)
SEC_KVECTOR = const(3)    # (kv_bins + 1) x "<I": the k-vector over the pair keys
SEC_TRIANGLES = const(4)  # TRI_HEADER, n_triangles x TRI_RECORD, k-vector (triangle)
SEC_HASH = const(5)       # HASH_HEADER, n_groups x HASH_RECORD, k-vector (hashing)
SECTION_NAMES = ("stars", "cells", "pairs", "kvector", "triangles", "hash", "reserved6",
                 "reserved7")

STAR_FORMAT = "<fffHH"       # x, y, z (float32), hip low 16 bits, packed word (below)
STAR_SIZE = 16
PAIR_FORMAT = "<HHH"         # key (angle / key_step, rounded), star a, star b (a < b)
PAIR_SIZE = 6
CELL_FORMAT = "<H"
KV_FORMAT = "<I"

# Star packed word: bit 0 = HIP bit 16; bits 1-11 = magnitude code (V = code / 100 - 2);
# bits 12-15 = flags.
MAG_OFFSET = 2.0
MAG_SCALE = 100
STAR_FLAG_PATTERN = 1        # flag bit: the star is in the pair table (a pattern star)
STAR_FLAG_TRIANGLE = 2       # flag bit: the star is a vertex of a stored triangle
STAR_FLAG_HASH = 4           # flag bit: the star is a member of a stored hash group

# Section 4 (triangles): a 40-byte section header, the records sorted by
# (area_key, moment_key, s0, s1, s2), zero padding to 4 bytes, then the k-vector over the area
# keys ((tri_kv_bins + 1) x "<I").  Section header fields (attributes "tri_" + name):
TRI_MAGIC = const(b"TRI1")
TRI_HEADER_FORMAT = const("<4sIIfffffHHf")
TRI_HEADER_FIELDS = const(("magic", "n", "kv_bins", "area_step", "moment_step", "max_side",
                           "kv_m", "kv_q", "regions_per_face", "stars_per_region",
                           "region_radius"))
TRI_HEADER_SIZE = const(40)
TRI_RECORD_FORMAT = "<HHHHH"  # area key, moment key, s0, s1, s2 (s0 opposite the shortest side)
TRI_RECORD_SIZE = 10

# Section 5 (hash): a 56-byte section header, the records sorted by (code, stars), zero
# padding to 4 bytes, then the k-vector over the codes.  Record: "<I" bucket code, then
# hash_group_size x "<H" star indices in the canonical order A, B, C(, D).
HASH_MAGIC = const(b"HSH1")
HASH_HEADER_FORMAT = const("<4sIIHHffHHfffffHHf")
HASH_HEADER_FIELDS = const(("magic", "n", "kv_bins", "group_size", "flags", "coord_lo",
                            "coord_bucket", "coord_buckets", "dist_buckets", "dist_bucket",
                            "min_diameter", "max_diameter", "kv_m", "kv_q", "regions_per_face",
                            "stars_per_region", "region_radius"))
HASH_HEADER_SIZE = const(56)
HASH_FLAG_DISTANCE = 1       # non-normalized hash: the code also keys the A-B angle
HASH_GROUP_SIZES = (3, 4)
HASH_MAX_CODE = 1 << 30      # codes stay MicroPython small ints

# Sections with a header of their own (magic first), then records sorted by key (the first
# field of a record), zero padding to 4 bytes and the k-vector over the keys.  Per section:
# (id, attribute prefix of the header fields, magic, header format, size, fields, key format).
KEYED_SECTIONS = ((SEC_TRIANGLES, "tri_", TRI_MAGIC, TRI_HEADER_FORMAT, TRI_HEADER_SIZE,
                   TRI_HEADER_FIELDS, "<H"),
                  (SEC_HASH, "hash_", HASH_MAGIC, HASH_HEADER_FORMAT, HASH_HEADER_SIZE,
                   HASH_HEADER_FIELDS, "<I"))

# The identification methods, in the order of their bits: the one table of the project.
# Per method: (name, bit in the header's ``methods`` mask, the flight module that implements
# it, the sections its images carry, the ground builder's options as (name, default) pairs).
# ``lodestar.firmware.starid`` imports the module; ``lodestar.firmware.database`` derives
# its masks and required sections; ``lodestar.ground.database`` its dispatch and options.
METHOD_TABLE = (
    ("pyramid", 1, "lodestar.firmware.starid.pyramid",
     (SEC_STARS, SEC_CELLS, SEC_PAIRS, SEC_KVECTOR),
     (("pairs_per_bin", 32),)),
    ("triangle", 2, "lodestar.firmware.starid.triangle",
     (SEC_STARS, SEC_CELLS, SEC_TRIANGLES),
     (("regions_per_face", 16), ("region_radius_deg", None), ("stars_per_region", 5),
      ("max_side_deg", None), ("per_bin", 4))),
    ("hashing", 4, "lodestar.firmware.starid.hashing",
     (SEC_STARS, SEC_CELLS, SEC_HASH),
     (("group_size", 4), ("normalized", False), ("regions_per_face", 16),
      ("region_radius_deg", None), ("stars_per_region", 6), ("max_diameter_deg", None),
      ("min_diameter_deg", None), ("coord_lo", -1.0), ("coord_bucket", 0.075),
      ("dist_bucket_deg", 0.25), ("per_bin", 4))),
)
METHODS = tuple(m[0] for m in METHOD_TABLE)
"""The method names, in the order of their bits."""
METHOD_NAMES = dict((m[0], m[1]) for m in METHOD_TABLE)
"""Method name -> its bit in the header's ``methods`` mask."""
METHOD_SECTIONS = dict((m[1], m[3]) for m in METHOD_TABLE)
"""Method bit -> the sections an image serving it carries."""
METHOD_MASK = sum(m[1] for m in METHOD_TABLE)
"""Every method bit: a ``methods`` mask with any other bit is not an image of this format."""
METHOD_PYRAMID = METHOD_NAMES["pyramid"]
METHOD_TRIANGLE = METHOD_NAMES["triangle"]
METHOD_HASHING = METHOD_NAMES["hashing"]
