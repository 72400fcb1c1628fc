"""Ground-side star-field simulator: catalogue, camera models, attitude, photometry, image
formation and sensor noise, scenes with truth, golden image sets and centroid scenes for the
identification (``docs/simulator.md``).

Frames, quaternion order, rates and units: ``docs/conventions.md``.
"""
