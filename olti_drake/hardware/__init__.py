"""hardware: the serial protocol, device drivers, the device emulators (SCARA, N-joint robot, 3D machine tool), the hardware station, the run log and the campaign runner."""
