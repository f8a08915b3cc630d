"""Robot programs read for compensation: one parser per controller language (docs/compensate.md).

Each language module (:mod:`~calib_oed.program.parse.krl`, ``rapid``, ``fanuc_tp``,
``urscript``, ``csv_targets``) finds the joint and Cartesian targets of a program
with the exact character spans of their numbers, so that
:mod:`calib_oed.program.compensate` can change those numbers and nothing else.
"""
