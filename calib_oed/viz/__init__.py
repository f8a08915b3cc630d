"""Inspection: the meshcat viewer, its drawing, and matplotlib plots.

Owns what a user looks at: the browser view of a design in its cell
(``viewer``, drawn with ``draw``; the robot at every design pose from one
copy of its meshes, ``instances``; the pose selector, ``selector``), live or
as a static HTML page (``sessions``), and the plots of ellipsoids and residuals (``plots``) and of
per-pose contributions and study results (``design_plots``). It may import
every package below it (through :mod:`calib_oed.oed`), never
:mod:`calib_oed.study` or :mod:`calib_oed.cli`.
"""
