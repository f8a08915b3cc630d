r"""Closed-form rigid registration: the tracker pose fitted alone, before any calibration.

The nominal model predicts every measured reflector centre in the world frame,
:math:`x_i = t_{W,F}(q_i) + R_{W,F}(q_i)\,c_{j_i}` [m]. The tracker measures the
same points in its own frame, :math:`\eta_i`. The tracker pose that best maps
one onto the other,

.. math::
    (\hat R, \hat t) = \arg\min_{R \in SO(3),\,t}\ \sum_i \lVert R\,\eta_i + t - x_i\rVert^2,

has a closed form (Kabsch): :math:`\hat R` aligns the centred point sets
(``scipy.spatial.transform.Rotation.align_vectors``, an SVD) and
:math:`\hat t = \bar x - \hat R\,\bar\eta`. The registration residual
:math:`e_i = \hat R\,\eta_i + \hat t - x_i` [m, world] is then the error of the
*nominal robot* alone, whatever the tracker pose: millimetres for a real arm
(its geometric errors), far more when the data or the scene are wrong (units,
swapped columns, a joint's sign). :mod:`calib_oed.calibration.sanity` uses it to
stop before fitting. ``T_{W,T} = (\hat R, \hat t)`` is the fitted tracker pose.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.parameters import ParameterSpace

MM_PER_M = 1e3


@dataclass(frozen=True, eq=False)
class Registration:
    """A rigid registration of measured points onto predicted ones.

    Attributes:
        rotation: :math:`\\hat R` (3, 3): measured frame to world.
        translation: :math:`\\hat t` (3,) [m].
        residuals: :math:`e_i = \\hat R\\eta_i + \\hat t - x_i` (n, 3) [m, world].
    """

    rotation: np.ndarray
    translation: np.ndarray
    residuals: np.ndarray

    @property
    def errors_mm(self) -> np.ndarray:
        """:math:`\\lVert e_i\\rVert` per row [mm]."""
        return np.linalg.norm(self.residuals, axis=1) * MM_PER_M

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.errors_mm**2)))

    @property
    def max_mm(self) -> float:
        return float(self.errors_mm.max())

    @property
    def placement(self) -> pin.SE3:
        """The fitted tracker pose :math:`T_{W,T}`."""
        return pin.SE3(self.rotation, self.translation)


def rigid_registration(world: np.ndarray, measured: np.ndarray) -> Registration:
    r"""The rigid motion :math:`(R, t)` minimising :math:`\sum_i\lVert R\,b_i + t - a_i\rVert^2`.

    Args:
        world: :math:`a_i`, (n, 3) [m], the points to map onto.
        measured: :math:`b_i`, (n, 3) [m], the points to move.

    With fewer than three non-collinear points the rotation about their line
    is not determined; scipy then returns one of the minimisers.
    """
    a = np.asarray(world, dtype=float)
    b = np.asarray(measured, dtype=float)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    with warnings.catch_warnings():  # degenerate (collinear) sets: any minimiser will do
        warnings.simplefilter("ignore", UserWarning)
        rot, _ = Rotation.align_vectors(a - ca, b - cb)
    r = rot.as_matrix()
    t = ca - r @ cb
    return Registration(r, t, b @ r.T + t - a)


def predicted_points(space: ParameterSpace, q: np.ndarray, reflector: np.ndarray,
                     p: np.ndarray | None = None, offsets: np.ndarray | None = None) -> np.ndarray:
    """World positions :math:`x_i` of the reflector of each row at parameters ``p`` (n, 3) [m].

    ``offsets`` (k, 3) [m] replaces the reflector offsets of ``p`` when given.
    """
    state = evaluate_setup(space, p, q, regressor=False, jacobian=False)
    c = state.reflectors if offsets is None else np.asarray(offsets, dtype=float)
    return state.kin.translation + np.einsum("nij,nj->ni", state.kin.rotation, c[reflector])


def register_tracker(space: ParameterSpace, mset: MeasurementSet) -> Registration:
    """The tracker pose fitted alone to the measured positions, the robot nominal."""
    return rigid_registration(predicted_points(space, mset.q, mset.reflector), mset.positions)


def pose_difference(a: pin.SE3, b: pin.SE3) -> tuple[float, float]:
    """Distance [mm] and angle [deg] between two poses."""
    d = a.inverse() * b
    return (float(np.linalg.norm(d.translation)) * MM_PER_M,
            float(np.degrees(np.linalg.norm(pin.log3(d.rotation)))))
