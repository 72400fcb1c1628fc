"""Star-identification database layout: one little-endian binary image that the ground
builder (``lodestar.ground.database``) writes and the flight reader
(``lodestar.firmware.database``) reads by offset.  The layout is specified in
``docs/stardb.md``; every value of it is here.  MicroPython-safe."""

MAGIC = b"LSDB"
VERSION = 1
HEADER_SIZE = 160

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
SEC_STARS = 0                # n_stars records of STAR_FORMAT
SEC_CELLS = 1                # (6 * cells_per_face**2 + 1) x "<H": first star of each cell
SEC_PAIRS = 2                # n_pairs records of PAIR_FORMAT, sorted by (key, a, b)
SEC_KVECTOR = 3              # (kv_bins + 1) x "<I": the k-vector over the pair keys
SEC_TRIANGLES = 4            # TRI_HEADER, n_triangles x TRI_RECORD, k-vector (triangle)
SEC_HASH = 5                 # HASH_HEADER, n_groups x HASH_RECORD, k-vector (hashing)
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

# Method bit mask and the sections each method needs.
METHOD_PYRAMID = 1
METHOD_TRIANGLE = 2
METHOD_HASHING = 4
METHODS = ("pyramid", "triangle", "hashing")
"""The identification methods, in the order of their bits: the one list of the project."""
METHOD_NAMES = dict(zip(METHODS, (METHOD_PYRAMID, METHOD_TRIANGLE, METHOD_HASHING)))
"""Method name -> its bit in the header's ``methods`` mask."""
METHOD_SECTIONS = {METHOD_PYRAMID: (SEC_STARS, SEC_CELLS, SEC_PAIRS, SEC_KVECTOR),
                   METHOD_TRIANGLE: (SEC_STARS, SEC_CELLS, SEC_TRIANGLES),
                   METHOD_HASHING: (SEC_STARS, SEC_CELLS, SEC_HASH)}

# Section 4 (triangles): a 40-byte section header, the records sorted by
# (area_key, moment_key, s0, s1, s2), zero padding to 4 bytes, then the k-vector over the area
# keys ((tri_kv_bins + 1) x "<I").  Section header fields (attributes "tri_" + name):
TRI_MAGIC = b"TRI1"
TRI_HEADER_FORMAT = "<4sIIfffffHHf"
TRI_HEADER_FIELDS = ("magic", "n", "kv_bins", "area_step", "moment_step", "max_side", "kv_m",
                     "kv_q", "regions_per_face", "stars_per_region", "region_radius")
TRI_HEADER_SIZE = 40
TRI_RECORD_FORMAT = "<HHHHH"  # area key, moment key, s0, s1, s2 (s0 opposite the shortest side)
TRI_RECORD_SIZE = 10

# Section 5 (hash): a 56-byte section header, the records sorted by (code, stars), zero
# padding to 4 bytes, then the k-vector over the codes.  Record: "<I" bucket code, then
# hash_group_size x "<H" star indices in the canonical order A, B, C(, D).
HASH_MAGIC = b"HSH1"
HASH_HEADER_FORMAT = "<4sIIHHffHHfffffHHf"
HASH_HEADER_FIELDS = ("magic", "n", "kv_bins", "group_size", "flags", "coord_lo",
                      "coord_bucket", "coord_buckets", "dist_buckets", "dist_bucket",
                      "min_diameter", "max_diameter", "kv_m", "kv_q", "regions_per_face",
                      "stars_per_region", "region_radius")
HASH_HEADER_SIZE = 56
HASH_FLAG_DISTANCE = 1       # non-normalized hash: the code also keys the A-B angle
HASH_GROUP_SIZES = (3, 4)
HASH_MAX_CODE = 1 << 30      # codes stay MicroPython small ints
