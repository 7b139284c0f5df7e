"""Benchmarks: commands that measure and print figures (`wftool bench …`), never pass/fail."""
