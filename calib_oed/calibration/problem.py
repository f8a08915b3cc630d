"""A calibration problem: robot, parameters, measurement models and KPI, assembled.

:class:`CalibrationProblem` is the driver: it owns no mathematics of its
own, it wires a scene's pieces together and caches the gauge selection.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property

import numpy as np

from calib_oed.calibration.covariance import kpi_covariance
from calib_oed.calibration.kpi import TcpKpi
from calib_oed.measurement import MeasurementModel
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.model.compliance import Compliance
from calib_oed.model.identifiability import (
    DEFAULT_TOL,
    Estimability,
    IdentifiabilityReport,
    check_estimability,
    select_gauge,
)
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.robot import Robot
from calib_oed.scene.records import GenericDesignSpec


class CalibrationProblem:
    """Everything needed to evaluate a calibration design.

    Args:
        space: Parameter layout (robot, tracker, reflectors).
        models: Measurement models, each applied at every design configuration.
        kpi: The key performance indicator.
        generic: The generic design of the gauge rule (default 200 configurations, seed 0).
        tol: Tolerance of the gauge rule.
        payload: The payload on the tool during the measurements (a scene's ``robot.compliance``
            payload, modelled or not); None: the compliance model's, if any. It loads the arm in
            the design prior (:func:`~calib_oed.calibration.joint_prior_choice.joint_prior`).
    """

    def __init__(
        self,
        space: ParameterSpace,
        models: Sequence[MeasurementModel],
        kpi: TcpKpi,
        generic: GenericDesignSpec | None = None,
        tol: float = DEFAULT_TOL,
        payload: Compliance | None = None,
    ):
        if not models:
            raise ValueError("a calibration problem needs at least one measurement model")
        self.space = space
        self.models = tuple(models)
        self.kpi = kpi
        self.generic = generic if generic is not None else GenericDesignSpec()
        self.tol = tol
        self.payload = payload if payload is not None else getattr(space, "compliance", None)
        space.robot.check_configurations(kpi.configurations, "kpi configurations")

    @property
    def robot(self) -> Robot:
        return self.space.robot

    @classmethod
    def from_scene(cls, scene) -> CalibrationProblem:
        """Assemble the problem of a :class:`calib_oed.scene.records.Scene`."""
        offsets = np.array([r.offset for r in scene.reflectors])
        compliance = getattr(scene, "compliance", None)
        space = ParameterSpace(scene.robot, scene.tracker.placement(), offsets,
                               compliance=compliance.model() if compliance is not None else None,
                               joint_gains=getattr(scene, "joint_gains", None))
        models = scene.error_model().models(range(len(offsets)))
        kpi = TcpKpi(
            np.array([w.q for w in scene.kpi.configurations]),
            point=scene.kpi.point,
            frame=scene.kpi.frame,
            names=[w.name for w in scene.kpi.configurations],
            reflector=scene.kpi.reflector,
            weights=[w.weight for w in scene.kpi.configurations],
        )
        generic = scene.generic_design
        return cls(space, models, kpi, generic, payload=compliance.payload if compliance is not None else None)

    # ------------------------------------------------------------ jacobians
    def weighted_jacobian(self, q: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
        r""":math:`F_1` over all parameters at design ``q`` (n, nq), (m, n_p)."""
        return weighted_jacobian(self.space, self.models, q, p)

    def kpi_jacobian(self, p: np.ndarray | None = None) -> np.ndarray:
        r""":math:`G = \partial s/\partial p` over all parameters, (3t, n_p)."""
        return self.kpi.compute_param_jacobian(self.space, p)

    def generic_configurations(self) -> np.ndarray:
        """The generic design of the gauge rule, (n, nq)."""
        return self.robot.random_configurations(self.generic.n, self.generic.seed)

    # ------------------------------------------------------- identifiability
    @cached_property
    def _generic_scaled_jacobian(self) -> np.ndarray:
        return self.weighted_jacobian(self.generic_configurations()) * self.space.unit_scale

    @cached_property
    def identifiability(self) -> IdentifiabilityReport:
        """The gauge rule on the generic design (computed once)."""
        return select_gauge(
            self._generic_scaled_jacobian,
            self.space.names,
            tol=self.tol,
            n_configurations=self.generic.n,
            seed=self.generic.seed,
        )

    def kpi_estimability(self) -> list[Estimability]:
        """Estimability of the KPI at each working configuration."""
        g = self.kpi_jacobian() * self.space.unit_scale
        return [
            check_estimability(
                self._generic_scaled_jacobian, g[3 * i : 3 * i + 3], self.identifiability, name
            )
            for i, name in enumerate(self.kpi.names)
        ]

    # ------------------------------------------------------------ covariance
    def kpi_covariance(self, q: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
        """KPI covariance :math:`C_s` (3t, 3t) [m²] of design ``q`` in the gauge."""
        free = self.identifiability.free_indices
        f1 = self.weighted_jacobian(q, p)[:, free]
        g = self.kpi_jacobian(p)[:, free]
        names = [self.space.names[i] for i in free]
        return kpi_covariance(f1, g, names)

    def kpi_sigma(self, q: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
        r"""Per working configuration :math:`\sqrt{\mathrm{tr}(C_{s,i})/3}` [m], (t,)."""
        cs = self.kpi_covariance(q, p)
        t = len(self.kpi.names)
        return np.sqrt(np.array([np.trace(cs[3 * i : 3 * i + 3, 3 * i : 3 * i + 3]) / 3
                                 for i in range(t)]))
