"""Units of the files calib_oed reads: their names and their value in SI.

Inside calib_oed every length is in metres and every angle in radians; scene
and measurement files declare ``units: {length: mm, angle: deg}`` and are
converted on reading with these tables.
"""

from __future__ import annotations

import math

#: Supported length units and their value in metres.
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3}
#: Supported angle units and their value in radians.
ANGLE_UNITS: dict[str, float] = {"rad": 1.0, "deg": math.pi / 180.0}
