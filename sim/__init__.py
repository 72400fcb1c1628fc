"""Ground-side star-field simulator: catalogue, camera models, image formation, truth.

Conventions (shared with the firmware and every test):

* **Inertial frame**: ICRS / J2000 equatorial.  The unit vector of right ascension ``ra`` and
  declination ``dec`` is ``(cos dec cos ra, cos dec sin ra, sin dec)``.
* **Camera frame**: ``+z`` is the boresight (out of the lens, towards the sky), ``+x`` points
  along increasing column ``x`` and ``+y`` along increasing row ``y`` of the image, so the
  frame is right-handed and the pinhole maps ``(X, Y, Z)`` to ``x = cx + fx X/Z``,
  ``y = cy + fy Y/Z`` with no sign flip (the lens' image inversion and the readout order are
  absorbed into this definition; the mounting calibration relates it to the spacecraft body).
  Pixel coordinates follow ``lodestar.contract``: pixel centre at the integer index.
* **Attitude**: a unit quaternion ``q = [x, y, z, w]`` (scalar last, the order of
  ``scipy.spatial.transform.Rotation``) of the rotation that takes inertial vectors into the
  camera frame: ``v_cam = Rotation.from_quat(q).apply(v_inertial)``.  Its matrix is the
  attitude matrix ``A`` of Shuster's Wahba problem (``b = A r``); note that Shuster's own
  quaternion for the same ``A`` is the conjugate ``[-x, -y, -z, w]``.
* **Rates**: ``omega`` is the camera's angular velocity in the camera frame, rad/s; a fixed
  star's camera-frame direction then moves as ``dv/dt = -omega x v``.
"""
