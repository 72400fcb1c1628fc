"""Ground-side tools for the flight software (numpy and scipy allowed): the star-identification
database builder (:mod:`lodestar.ground.database`) and synthetic centroid scenes for testing
the identification (:mod:`lodestar.sim.centroids`).  Nothing here runs on the MCU; the flight
readers live in ``lodestar.firmware``."""
