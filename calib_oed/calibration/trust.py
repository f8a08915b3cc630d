r"""What an identification's numbers are worth: model error, predicted accuracy, plausibility.

:func:`assess` takes a robust identification with a model-error fit
(:func:`calib_oed.calibration.robust.identify_robust` with ``model_error=``) and
assembles what ``calib-oed identify`` reports beside the parameters:

- the model error's hyperparameters (restricted likelihood,
  :mod:`calib_oed.calibration.model_error`);
- the predicted accuracy of the calibrated model (:mod:`calib_oed.calibration.prediction`),
  without and with the fitted model error's mean compensated, with the 95 % range of the
  new-pose RMS and the widened prediction regions that the uncertainty of the fitted model
  error gives (:mod:`calib_oed.calibration.hyper_uncertainty`);
- the data a later ``validate --compensate`` needs to add that mean: the
  distinct training configurations and the weights
  :math:`\beta = \Sigma^{-1}e` summed per configuration and component, so that
  :math:`\mu_c(q) = \sum_P k(q, q_P)\,\beta_{P,c}` [m] in the tracker frame;
- the training joint ranges (``validate`` warns for poses outside them);
- plausibility warnings (:mod:`calib_oed.calibration.plausibility`);
- the linearised identification (``prediction_data``: :math:`J`, the noise blocks, the
  residuals, the configurations, the free parameters' names), from which ``validate``
  predicts the error at each of its poses
  (:mod:`calib_oed.calibration.pose_prediction`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from calib_oed.calibration.hyper_uncertainty import laplace_covariance
from calib_oed.calibration.joint_prior_choice import joint_prior as prior_of
from calib_oed.calibration.model_error import Linearisation
from calib_oed.calibration.plausibility import Implausible, check_plausibility
from calib_oed.calibration.prediction import PredictedAccuracy, predict_accuracy
from calib_oed.calibration.robust import RobustIdentification
from calib_oed.calibration.world_frame import JointErrorModel, row_offsets
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.joint_prior import JointErrorPrior
from calib_oed.measurement.position import TrackerPosition


def compensation_weights(lin: Linearisation, prior: DiscrepancyPrior) -> tuple[np.ndarray, np.ndarray]:
    r"""Distinct configurations (P, nq) and :math:`\beta` (P, 3) [1/m] (module docstring)."""
    beta = scipy.linalg.cho_solve(scipy.linalg.cho_factor(lin.covariance(prior), lower=True),
                                  lin.residual)
    configs, index = np.unique(lin.q, axis=0, return_inverse=True)
    index = index.ravel()
    weights = np.zeros((configs.shape[0], 3))
    pos = lin.position
    np.add.at(weights, (index[pos], lin.component[pos]), beta[pos])
    return configs, weights


def compensate(prior: DiscrepancyPrior, configs: np.ndarray, weights: np.ndarray,
               q: np.ndarray) -> np.ndarray:
    r""":math:`\mu(q)` (n, 3) [m], tracker frame, from :func:`compensation_weights`' output."""
    return prior.covariance_kernel(np.asarray(q, float), configs) @ weights


@dataclass(frozen=True, eq=False)
class Trust:
    """The assessment of one identification (module docstring).

    Attributes:
        prior: The fitted model-error prior.
        predicted: Predicted accuracy, uncompensated.
        predicted_compensated: The same with the model error's mean added.
        configs, weights: Compensation data (:func:`compensation_weights`), SI.
        joint_ranges: Training joint ranges, (nq, 2) [rad or m].
        implausible: Plausibility warnings.
    """

    prior: DiscrepancyPrior
    predicted: PredictedAccuracy
    predicted_compensated: PredictedAccuracy
    configs: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    joint_ranges: np.ndarray = field(repr=False)
    joint_names: tuple[str, ...] = ()
    implausible: tuple[Implausible, ...] = ()
    linearisation: Linearisation | None = field(default=None, repr=False)
    free_names: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        out = {
            "predicted_accuracy": {"uncompensated": self.predicted.to_dict(),
                                   "compensated": self.predicted_compensated.to_dict()},
            "compensation": {"configurations_rad": self.configs.tolist(),
                             "weights_per_m": self.weights.tolist(),
                             "frame": "tracker",
                             "meaning": "mu_c(q) = sum_P k(q, q_P) w_P,c [m], k = model_error.fitted"},
            "training_joint_ranges": {n: [float(a), float(b)] for n, (a, b)
                                      in zip(self.joint_names, self.joint_ranges, strict=True)},
            "implausible": [w.to_dict() for w in self.implausible],
        }
        if self.linearisation is not None:
            out["prediction_data"] = {"free_names": list(self.free_names),
                                      **self.linearisation.to_dict()}
        return out

    def lines(self) -> list[str]:
        out = [self.prior.describe()]
        out += self.predicted.lines()
        comp = self.predicted_compensated
        out.append(f"  with the fitted model error's mean compensated (validate --compensate), tracker frame: "
                   f"new poses {comp.new_pose_rms_mm:.4f} mm RMS; TCP "
                   + ", ".join(f"{n} {r:.4f}" for n, r in zip(comp.names, comp.tcp_rms_mm, strict=True))
                   + " mm RMS")
        out += [w.line() for w in self.implausible]
        return out


def assess(problem, robust: RobustIdentification, feasibility=None, blocks=None,
           joint_prior: JointErrorPrior | None = None) -> Trust:
    """:class:`Trust` of ``robust`` (identified with a model-error prior) for ``problem``;
    ``feasibility``: the scene's constraints, so that the expected RMS on new poses is over
    feasible poses in the training joint ranges (None: uniform in those ranges); ``blocks``: the
    data ``robust`` was identified from, for the world-frame numbers with ``joint_prior``
    (None: :func:`~calib_oed.calibration.joint_prior_choice.joint_prior`, the size-class default;
    :mod:`calib_oed.calibration.world_frame`). Without ``blocks``, or with measurements other than
    reflector positions, the prediction is in the tracker frame only."""
    if robust.model_error is None or robust.linearisation is None:
        raise ValueError("assess needs identify_robust(..., model_error=prior)")
    lin, prior, res = robust.linearisation, robust.model_error.prior, robust.result
    free = np.asarray(res.free_indices)
    q_train = np.unique(lin.q, axis=0)
    joint = None
    if blocks is not None and all(isinstance(b.model, TrackerPosition) for b in blocks):
        joint = JointErrorModel.build(problem.space, lin, joint_prior or prior_of(problem), res.p,
                                      row_offsets(problem.space, blocks, robust))
    args = (problem, lin, prior, res.p, free, q_train)
    configs, weights = compensation_weights(lin, prior)
    spread = laplace_covariance(lin, prior)
    return Trust(prior, predict_accuracy(*args, spread=spread, feasibility=feasibility, joint=joint),
                 predict_accuracy(*args, compensate=True, spread=spread, feasibility=feasibility, joint=joint),
                 configs, weights, np.stack([q_train.min(axis=0), q_train.max(axis=0)], axis=1),
                 tuple(problem.robot.joint_names),
                 tuple(check_plausibility(problem.space, res.free_names, res.p[free],
                                          robust.parameter_std)),
                 lin, tuple(res.free_names))
