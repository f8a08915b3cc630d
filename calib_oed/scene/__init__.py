"""Scenes: the cell a calibration happens in, as the user describes it in YAML.

Owns the scene records (robot, tracker, reflectors, KPI, cell, feasibility
settings, compliance), the scene file reader and its cell section, the
scaling of a scene to another robot, and the shipped scenes (``shipped/``).
It may import :mod:`calib_oed.model`, :mod:`calib_oed.feasibility` (the shape
records) and the base modules, nothing above.
"""
