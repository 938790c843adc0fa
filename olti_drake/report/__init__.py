"""report: the papers' figures, ISO 230-2 statistics, the HTML calibration report, validation, diagram pictures, the six-axis demo."""
