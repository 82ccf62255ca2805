"""substation-twin: a reproducible build system for digital twins of substations."""

__version__ = "0.1.0"
