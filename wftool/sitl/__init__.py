"""The virtual FC: the patched SITL as a process (`process.VirtualFC`) and as a flight
controller with FSP set up and in motion (`session.VirtualFcSession`)."""
