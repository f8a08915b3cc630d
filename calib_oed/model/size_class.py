"""Size classes of serial arms by their URDF mass, and each class's typical joint stiffness, gear
ratios and J2 balancer share (the published magnitudes behind the realistic simulator,
:mod:`calib_oed.calibration.realistic_defaults`, and the design's joint-space model-error prior,
:mod:`calib_oed.measurement.joint_prior`; sources in the former's docstring)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Size classes by the arm's URDF mass [kg]: (name, lower bound).
SIZE_CLASSES = (("small", 0.0), ("medium", 50.0), ("large", 300.0))


@dataclass(frozen=True)
class SizeDefaults:
    """Typical values of one size class (J1..J6; extra joints repeat the last).

    Attributes:
        stiffness: Joint stiffness (6,) [N·m/rad].
        gear_ratios: Motor turns per joint turn (6,).
        balancer_fraction: Share of the J2 gravity torque the balancer carries [1].
    """

    stiffness: np.ndarray
    gear_ratios: np.ndarray
    balancer_fraction: float


TYPICAL = {
    "small": SizeDefaults(np.array([1.5e5, 1.5e5, 1.0e5, 3e4, 3e4, 2e4]),
                          np.array([100.0, 100, 100, 100, 100, 100]), 0.0),
    "medium": SizeDefaults(np.array([6e5, 1.0e6, 6e5, 1.5e5, 1.2e5, 8e4]),
                           np.array([150.0, 150, 120, 90, 80, 50]), 0.5),
    "large": SizeDefaults(np.array([2e6, 4e6, 2e6, 5e5, 4e5, 2.5e5]),
                          np.array([180.0, 200, 160, 100, 90, 60]), 0.5),
}


def arm_mass(model) -> float:
    """Total mass of a Pinocchio model's moving bodies [kg] (the URDF's inertials)."""
    return float(sum(model.inertias[i].mass for i in range(1, model.njoints)))


def size_class_of(mass: float) -> str:
    """The size class of an arm of ``mass`` [kg] (:data:`SIZE_CLASSES`)."""
    name = SIZE_CLASSES[0][0]
    for cls, lower in SIZE_CLASSES:
        if mass >= lower:
            name = cls
    return name


def per_joint(typical: np.ndarray, nv: int) -> np.ndarray:
    """A J1..J6 table for ``nv`` joints: extra joints repeat the last value, fewer drop the tail."""
    return np.resize(np.concatenate([typical, np.repeat(typical[-1:], max(0, nv - 6))]), nv)
