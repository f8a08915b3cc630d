"""The version of calib_oed (written into exported files)."""

__version__ = "0.1.0"
