"""Evaluating the firmware from data: spectra of recordings, the accelerometer RPM filter.

Everything here needs the `analysis` extra (NumPy, SciPy, Matplotlib, Unicorn); modules
import those lazily where a caller may only want to check for them (`wftool.extras.require`).
"""
