"""Ground uses of the flight software (numpy and scipy allowed): the star database builder and
its cache, the packet codec, the flight settings and solve (``flight``), centroid and image
solves, lens calibration and camera files, WCS headers, annotated pictures, checks against
the simulator's truth and the Monte-Carlo campaigns (``campaign``).  Nothing here runs on the
MCU; the flight code is ``lodestar.firmware``, the simulator ``lodestar.sim``.
"""
