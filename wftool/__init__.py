"""wftool: build, flash, configure and verify the Weitflug research firmware."""

__version__ = "0.1.0"
