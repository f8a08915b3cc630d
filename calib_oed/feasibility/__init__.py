"""Feasibility of measurement configurations: capsules, cell, beam, incidence, limits."""

from calib_oed.feasibility.shapes import Capsule, Cell, FeasibilitySettings, HalfSpace, Margins

__all__ = ["Capsule", "Cell", "FeasibilitySettings", "HalfSpace", "Margins"]
