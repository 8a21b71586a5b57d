"""The version of idbench, recorded with every result it writes."""

__version__ = "0.1.0"
