"""olti_drake: open-loop tracking interferometer calibration on Drake.

Papers: 000 = Ibaraki & Usui, bidirectional angular positioning deviation error
map of a SCARA robot by "open-loop" tracking interferometer; 001 = the
machine-tool self-calibrated multilateration. Importing this package does not
import pydrake; the modules that need it import it themselves.
"""

__version__ = "0.1.0"
