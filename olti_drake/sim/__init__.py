"""sim: scenarios, Drake plants and systems, the station factory, the campaign diagram (SCARA; N-joint robots: serial_scenario, serial_station), the Meshcat view, simulated reference instruments."""
