r"""Plausibility of identified parameters: documented bounds, a warning for each value beyond one.

A parameter can fit the data and still be physically implausible: it then
absorbs error the model does not have a term for (a stiffness that is really a
gear error, a gain that is really gravity). The bounds, per parameter kind
(``docs/identification.md``, "Plausibility"):

- **joint changes** ``joint{i}.tx..tz``: :math:`|\delta| \le` :data:`MAX_LENGTH_CHANGE`
  (5 mm) per metre of reach, at least 5 mm; ``joint{i}.rx..rz``:
  :math:`|\delta| \le` :data:`MAX_ANGLE_CHANGE` (10 mrad = 0.57 deg; a zero
  offset beyond that is a mastering error to fix at the robot, not to calibrate);
- **joint compliance** ``joint{i}.c``: :math:`0 \le c \le 1/k_{\min}` with
  :math:`k_{\min} =` :data:`STIFFNESS_PER_REACH3` :math:`\times (\mathrm{reach}/1\,\mathrm{m})^3`
  [N·m/rad] (1e4 for a 1 m arm, 2e5 for a 2.7 m one: joint stiffness of
  industrial arms grows about with the cube of their size); negative is a
  negative stiffness;
- **joint gains and coupling ratios**: :math:`|g| \le` :data:`MAX_GAIN` (3e-3 = 0.3 %;
  gear-ratio and encoder errors are 1e-4..1e-3, and the simulator draws them with a
  standard deviation of 1e-3, :func:`calib_oed.calibration.simulation.draw_true_parameters`:
  three of its standard deviations, so a simulated truth's gain is called implausible
  about once in 400 draws, and issue 29's -0.5 % J2 gain still is).

The tracker pose and the reflector offsets have no bound (they are where the
set-up put them). A value is reported only when it is beyond its bound by more
than two of its standard deviations (under noise + model error), so a poorly
determined parameter is not called implausible for its noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.measurement.discrepancy import robot_reach

#: Largest plausible change of a joint placement's translation per metre of reach [m/m].
MAX_LENGTH_CHANGE = 5e-3
#: Largest plausible change of a joint placement's rotation [rad].
MAX_ANGLE_CHANGE = 1e-2
#: Smallest plausible joint stiffness of a 1 m arm [N·m/rad]; scales with reach cubed.
STIFFNESS_PER_REACH3 = 1e4
#: Largest plausible joint gain or coupling ratio error [1].
MAX_GAIN = 3e-3
#: Standard deviations a value must be beyond its bound to be reported.
SIGNIFICANCE = 2.0


@dataclass(frozen=True)
class Implausible:
    """One identified value beyond its bound (report units: mm, mrad, N·m/rad, %).

    Attributes:
        name: Parameter. value, bound: In ``unit``. cause: The likely cause, in words.
    """

    name: str
    value: float
    bound: str
    unit: str
    cause: str

    def line(self) -> str:
        return (f"warning: {self.name} = {self.value:.4g} {self.unit} is implausible (bound "
                f"{self.bound}): {self.cause}")

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "unit": self.unit, "bound": self.bound,
                "cause": self.cause}


_ABSORBS = ("likely the parameter absorbing error the model has no term for (model error "
            "correlated with its effect), or a wrong nominal value")


def check_plausibility(space, names, values, std) -> list[Implausible]:
    """The implausible ones among the free parameters ``names`` with ``values`` and ``std`` [SI]."""
    reach = robot_reach(space.robot)
    max_len = MAX_LENGTH_CHANGE * max(reach, 1.0)
    k_min = STIFFNESS_PER_REACH3 * reach**3
    out = []
    for name, v, s in zip(names, values, std, strict=True):
        margin = SIGNIFICANCE * (s if np.isfinite(s) else 0.0)
        if not name.startswith("joint"):
            continue
        kind = name.split(".")[-1]
        if kind in ("tx", "ty", "tz") and abs(v) - margin > max_len:
            out.append(Implausible(name, v * 1e3, f"|change| <= {max_len * 1e3:.1f} mm "
                                   f"(5 mm per m of reach, {reach:.2f} m)", "mm", _ABSORBS))
        elif kind in ("rx", "ry", "rz") and abs(v) - margin > MAX_ANGLE_CHANGE:
            out.append(Implausible(name, v * 1e3, f"|change| <= {MAX_ANGLE_CHANGE * 1e3:.0f} mrad",
                                   "mrad", _ABSORBS + "; a zero offset this large is a mastering "
                                   "error to correct at the robot"))
        elif kind == "c" and (v + margin < 0 or v - margin > 1.0 / k_min):
            stiffness = 1.0 / v if v != 0 else np.inf
            cause = ("a negative compliance is a negative stiffness: " if v < 0 else
                     "softer than any joint of an arm this size: ") + _ABSORBS \
                + " (gravity acts on the same poses as many other errors)"
            out.append(Implausible(name.replace(".c", " stiffness"), stiffness,
                                   f">= {k_min:.3g} N m/rad (1e4 x reach^3, reach {reach:.2f} m)",
                                   "N m/rad", cause))
        elif (kind == "gain" or kind.startswith("coupling")) and abs(v) - margin > MAX_GAIN:
            out.append(Implausible(name, v * 100, f"|g| <= {MAX_GAIN * 100:g} %", "%",
                                   _ABSORBS + "; gear and encoder errors are 0.01-0.1 %"))
    return out
