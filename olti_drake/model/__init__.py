"""model: joint spaces, error maps, position models of serial robots in 3D, the reading and its error budget,
the uncertainty of a prediction from a covariance (``propagation``), the free points of 001 (``free_points``),
the distance measurement from stations (``measurements``) over any position model of one protocol
(``position_model``), and the named gauges of 001, the SCARA and the volumetric machine (``gauges``).

Imports no other layer (only the top-level modules of olti_drake); files are read and written in io.
"""
