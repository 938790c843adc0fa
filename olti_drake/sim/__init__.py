"""sim: scenarios, Drake plants and systems, the station factory, the campaign diagram, the Meshcat view, simulated reference instruments."""
