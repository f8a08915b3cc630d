"""Inspection: the meshcat viewer, its drawing, and matplotlib plots.

Owns what a user looks at: the browser view of a design in its cell, the
static HTML page, and the plots of ellipsoids, per-pose contributions and
residuals. It may import every package below it (through
:mod:`calib_oed.oed`), never :mod:`calib_oed.study` or :mod:`calib_oed.cli`.
"""
