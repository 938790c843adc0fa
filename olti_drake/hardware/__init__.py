"""hardware: the serial protocol, device drivers, the device emulator, the hardware station, the run log and the campaign runner."""
