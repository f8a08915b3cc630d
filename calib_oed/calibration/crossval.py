r"""K-fold cross-validation over poses: the accuracy a calibration will have on poses it has not seen.

Poses (distinct configurations; every reflector measured there goes with
its pose) are split into :math:`K` folds; each fold is predicted by the
calibration identified from the other :math:`K-1` (linear weighted least
squares, every row: flagged rows too), and the held-out position errors
:math:`\lVert\eta_i - h(\hat p_{-f}, q_i)\rVert` [mm] pooled over all folds give
the predicted RMS error on unseen poses.

**Every row.** Every row is held out once and counts in the held-out error: rows
the identification flags as likely model error are what new poses will show, and
leaving them out made CV optimistic (3.6x on a real arm, issue 29). The folds
train as the identification does: on every row but those it drops as gross errors
(``gross=``, a misread reflector beyond 10 standard deviations of noise + model
error, decided once on all the data); a fold trained on a 5 mm misreading would
judge a calibration nobody uses. A held-out gross row counts in the error like any
other; the summary counts them and gives the held-out RMS without them beside the
RMS over every row, so the user sees what they weigh.

**Balanced folds** (:func:`balanced_folds`). A random split of sweep-structured
data can hold out most of one joint's range, and the calibration then
extrapolates. Every joint's values are cut into :math:`K` quantile bins; poses,
in a seeded random order, go to the fold (among those not yet full) that has
the fewest poses in the same bins, so each fold samples every joint's range.
:func:`coverage_warnings` then checks, per fold and joint, that every held-out
pose has a training pose within 15 % of the joint's measured range.

**Uncertainty.** With :math:`e_p` the sum of squared held-out errors of pose
:math:`p` and :math:`n_p` its rows, :math:`\mathrm{RMS}^2 = \sum e_p/\sum n_p`
(a ratio estimator over independent poses); its standard error is
:math:`\mathrm{sd}_p(e_p - \mathrm{RMS}^2 n_p)/(\sqrt P\,\bar n)`, and that of the
RMS half of it divided by the RMS (delta method). Poses are not independent
under a smooth model error: given the model error (``model_error=``, as
``identify --cv`` does with the fitted one), the standard error is instead that of
CV's RMS as a prediction of the RMS on new poses in the training ranges, from the
Gaussian-process covariance of all the held-out and new errors
(:mod:`calib_oed.calibration.crossval_error`), and CV's expected excess over that
RMS (``bias_mm``: the folds train on fewer poses, and a design confined to part
of the joint-range box, as in a cell, leaves new poses of the box farther from
any training pose than its own poses are from each other) is reported beside it.

**Noise floor** (:func:`noise_floor`): the RMS position error a perfect model
would show, :math:`\sqrt{\mathrm{mean}_i\, E\lVert e_i\rVert^2}` with
:math:`E\lVert e_i\rVert^2 = \mathrm{tr}\,\Sigma_i` [m²]: :math:`\sum_a \sigma_a^2`
for the isotropic ``sigma``, and with the scene's tracker error model and
repeatability (``scene.position_noise()``) :math:`\Sigma_i` evaluated at the measured
position in the tracker frame, :math:`\sigma_r^2 + 2\sigma_t^2 + 3\rho^2`
(range-dependent). The cross-validation and ``calib-oed validate`` report the held-out
RMS against it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_oed.calibration.crossval_error import cv_difference
from calib_oed.calibration.identification import identify
from calib_oed.calibration.model_error import linearise
from calib_oed.exceptions import NotIdentifiableError, ParameterError
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.error_model import ErrorModel
from calib_oed.model.parameters import ParameterSpace

MM_PER_M = 1e3
#: A held-out pose farther than this fraction of a joint's measured range from every
#: training pose gets a warning.
COVERAGE_GAP = 0.15


def pose_index(q: np.ndarray) -> np.ndarray:
    """Pose number of every row (0-based, distinct configurations in order of first appearance)."""
    _, first, inverse = np.unique(np.asarray(q), axis=0, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))
    return order[inverse.ravel()]


def balanced_folds(poses: np.ndarray, k: int, seed: int | np.random.Generator = 0) -> np.ndarray:
    """Fold (0..k-1) of every pose of ``poses`` (P, nq), balanced over each joint's quantiles."""
    poses = np.asarray(poses, dtype=float)
    n = poses.shape[0]
    if not 2 <= k <= n:
        raise ParameterError(f"cross-validation folds: K must be between 2 and the number of poses "
                             f"({n}), got {k}")
    rng = np.random.default_rng(seed)
    ranks = np.argsort(np.argsort(poses, axis=0, kind="stable"), axis=0)
    bins = ranks * k // n  # (P, nq): quantile bin of each joint value
    counts = np.zeros((k, poses.shape[1], k), dtype=int)
    size = np.zeros(k, dtype=int)
    cap = -(-n // k)
    fold = np.empty(n, dtype=int)
    for i in rng.permutation(n):
        open_ = np.flatnonzero(size < cap)
        cost = counts[open_[:, None], np.arange(poses.shape[1]), bins[i]].sum(axis=1)
        best = open_[np.lexsort((rng.random(open_.size), size[open_], cost))[0]]
        fold[i] = best
        counts[best, np.arange(poses.shape[1]), bins[i]] += 1
        size[best] += 1
    return fold


def coverage_warnings(poses: np.ndarray, fold: np.ndarray, joint_names,
                      gap: float = COVERAGE_GAP) -> list[str]:
    """Folds whose held-out poses reach a part of a joint's range no training pose covers.

    Per fold and joint: the largest distance from a held-out value to the nearest
    training value; above ``gap`` times the joint's measured range, the warning
    names the fold, the joint and that stretch [deg].
    """
    out = []
    poses = np.asarray(poses, dtype=float)
    span = np.ptp(poses, axis=0)
    k = int(fold.max()) + 1
    for f in range(k):
        test, train = poses[fold == f], poses[fold != f]
        for j, name in enumerate(joint_names):
            if span[j] == 0 or train.shape[0] == 0:
                continue
            d = np.abs(test[:, j, None] - train[None, :, j]).min(axis=1)
            i = int(np.argmax(d))
            if d[i] > gap * span[j]:
                out.append(f"fold {f + 1} of {k}: a held-out pose has {name} = "
                           f"{np.degrees(test[i, j]):.0f} deg, {np.degrees(d[i]):.0f} deg from the "
                           f"nearest training pose ({100 * d[i] / span[j]:.0f} % of the measured "
                           "range): the calibration extrapolates there")
    return out


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """Held-out errors of a K-fold cross-validation.

    Attributes:
        k: Folds. seed: Of the fold assignment.
        fold: Fold of every measurement row (n,): every row is used, flagged or not.
        errors_mm: Held-out position error per row [mm].
        rms_mm, se_mm: Pooled held-out RMS and its standard error [mm].
        se_basis: ``"independent poses"`` or ``"model error"`` (module docstring).
        bias_mm: With the model error: CV's expected RMS minus the new poses' [mm], else None.
        fold_rms_mm: Per fold [mm].
        noise_floor_mm: RMS a perfect model would show (measurement noise, :func:`noise_floor`) [mm].
        warnings: Coverage warnings (:func:`coverage_warnings`).
        gross: Per row (n,): rows the identification drops as gross errors, left out of the
            folds' training, in the held-out error (None: not given).
    """

    k: int
    seed: int
    fold: np.ndarray = field(repr=False)
    errors_mm: np.ndarray = field(repr=False)
    rms_mm: float
    se_mm: float
    fold_rms_mm: tuple[float, ...]
    noise_floor_mm: float
    warnings: tuple[str, ...]
    se_basis: str = "independent poses"
    bias_mm: float | None = None
    gross: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_gross(self) -> int:
        """Rows the identification drops as gross errors, all in the held-out error."""
        return 0 if self.gross is None else int(np.sum(self.gross))

    @property
    def rms_without_gross_mm(self) -> float:
        """The held-out RMS over the rows the identification keeps [mm]."""
        keep = np.ones(self.errors_mm.size, bool) if self.gross is None else ~self.gross
        return float(np.sqrt(np.mean(self.errors_mm[keep] ** 2))) if keep.any() else float("nan")

    def _rows_words(self) -> str:
        words = f"every one of the {self.fold.size} rows used (flagged rows too"
        if self.gross is None:
            return words + ")"
        if self.n_gross == 0:
            return words + "; no gross error)"
        return (words + f"; {self.n_gross} row(s) the identification drops as gross errors are left "
                f"out of the folds' training as there and count in the held-out error, RMS "
                f"{self.rms_without_gross_mm:.4f} mm without them)")

    def summary(self) -> str:
        lines = [f"cross-validation, {self.k} folds balanced over the joint ranges (seed {self.seed}), "
                 f"{self._rows_words()}: "
                 f"predicted position error on unseen poses RMS {self.rms_mm:.4f} ± {self.se_mm:.4f} mm "
                 f"(standard error, {self._se_words()}; noise floor {self.noise_floor_mm:.4f} mm, "
                 f"ratio {self.rms_mm / self.noise_floor_mm:.2f})",
                 "  per fold RMS [mm]: " + ", ".join(f"{r:.4f}" for r in self.fold_rms_mm)]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def _se_words(self) -> str:
        if self.bias_mm is None:
            return "poses taken as independent"
        word = "above" if self.bias_mm >= 0 else "below"
        return (f"as a prediction of new poses uniform in the training joint ranges, under the "
                f"fitted model error, which nearby poses share; CV expected "
                f"{abs(self.bias_mm):.4f} mm {word} their RMS")

    def to_dict(self) -> dict:
        return {"k": self.k, "seed": self.seed, "rms_mm": self.rms_mm, "se_mm": self.se_mm,
                "se_basis": self.se_basis, "bias_mm": self.bias_mm,
                "fold_rms_mm": list(self.fold_rms_mm), "noise_floor_mm": self.noise_floor_mm,
                "warnings": list(self.warnings), "rows": int(self.fold.size),
                "rows_used": "all held out (flagged and gross rows too); gross rows not trained on",
                "gross_rows": None if self.gross is None else self.n_gross,
                "rms_without_gross_mm": None if self.gross is None else self.rms_without_gross_mm}


def subset(mset: MeasurementSet, rows: np.ndarray) -> MeasurementSet:
    """The rows ``rows`` (indices or mask) of a measurement set, lines kept."""
    rows = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows, dtype=int)
    pick = (lambda a: None if a is None else a[rows])  # noqa: E731
    return MeasurementSet(mset.joint_names, mset.q[rows], mset.reflector[rows], mset.positions[rows],
                          pick(mset.rotations), pick(mset.sigma), mset.source, mset.lines[rows])


def noise_floor(mset: MeasurementSet, blocks) -> float:
    """RMS position error [m] a perfect model shows on ``mset``: :math:`\\sqrt{\\mathrm{mean}_i\\,
    \\mathrm{tr}\\,\\Sigma_i}` (module docstring), ``blocks`` = ``mset.blocks(...)``."""
    var = np.empty(mset.n)
    for j, block in zip(mset.reflectors, blocks, strict=True):  # Sigma_i at the measured position
        cov = block.model.noise_covariance(block.values, block.sigma)[:, :3, :3]
        var[mset.reflector == j] = np.trace(cov, axis1=1, axis2=2)
    return float(np.sqrt(np.mean(var)))


def held_out_errors(space: ParameterSpace, mset: MeasurementSet, p: np.ndarray | None,
                    error_model: ErrorModel) -> np.ndarray:
    """Position error :math:`\\lVert\\eta - h(p, q)\\rVert` per row of ``mset`` [mm]
    (``error_model``: ``scene.error_model()``, only to build the blocks)."""
    out = np.empty(mset.n)
    for j, block in zip(mset.reflectors, mset.blocks(error_model=error_model), strict=True):
        state = evaluate_setup(space, p, block.q, regressor=False, jacobian=False)
        predicted = block.model.compute_values(state)
        out[mset.reflector == j] = np.linalg.norm(block.values[:, :3] - predicted[:, :3], axis=1)
    return out * MM_PER_M


def cross_validate(space: ParameterSpace, mset: MeasurementSet, free, k: int, *,
                   error_model: ErrorModel, seed: int = 0,
                   model_error: DiscrepancyPrior | None = None,
                   gross: np.ndarray | None = None) -> CrossValidation:
    """K-fold cross-validation over the poses of ``mset``, every row included.

    No row is left out, flagged or not: a flagged row that is model error is what
    new poses will show too, and leaving it out made the prediction optimistic.
    ``error_model``: the measurement model of the fits and of the noise floor
    (``scene.error_model()``); ``model_error``: the standard error against new poses under
    this model error (module docstring), None: poses taken as independent; ``gross``:
    per row of ``mset``, those the identification drops as gross errors (counted in the
    summary, module docstring).

    Raises:
        ParameterError: K not in 2..number of poses.
        NotIdentifiableError: a fold's training poses do not determine the parameters
            (the message names the fold; use fewer folds).
    """
    data = mset
    if gross is not None:
        gross = np.asarray(gross, dtype=bool)
        if gross.shape != (data.n,):
            raise ParameterError(f"cross-validation: gross must flag each of the {data.n} rows, "
                                 f"got shape {gross.shape}")
    pose = pose_index(data.q)
    poses = data.q[np.unique(pose, return_index=True)[1]]
    fold_of_pose = balanced_folds(poses, k, seed)
    fold = fold_of_pose[pose]
    errors = np.empty(data.n)
    fold_rms = []
    for f in range(k):
        train = subset(data, (fold != f) if gross is None else (fold != f) & ~gross)
        test = subset(data, fold == f)
        try:
            result = identify(space, train.blocks(error_model=error_model), free)
        except NotIdentifiableError as exc:
            raise NotIdentifiableError(exc.names, f"cross-validation fold {f + 1} of {k}: its "
                                       f"{int((fold != f).sum())} training rows do not determine "
                                       "them; use fewer folds (--cv)") from exc
        e = held_out_errors(space, test, result.p, error_model)
        errors[fold == f] = e
        fold_rms.append(float(np.sqrt(np.mean(e**2))))
    e_pose = np.bincount(pose, errors**2)
    n_pose = np.bincount(pose).astype(float)
    ms = e_pose.sum() / n_pose.sum()
    se_ms = np.std(e_pose - ms * n_pose, ddof=1) / (np.sqrt(e_pose.size) * n_pose.mean())
    rms = float(np.sqrt(ms))
    blocks = data.blocks(error_model=error_model)
    floor = noise_floor(data, blocks)
    basis, bias = "independent poses", None
    if model_error is not None:
        full = identify(space, blocks, free)
        lin = linearise(space, blocks, full.p, full.free_indices)
        fold_meas = np.concatenate([fold[data.reflector == j] for j in data.reflectors])
        mean_d, sd_d = cv_difference(lin, model_error, fold_meas, space, full.p, full.free_indices,
                                     [b.model for b in blocks])
        rms_si = rms / MM_PER_M
        se_ms = sd_d * MM_PER_M**2
        basis = "model error"
        bias = float(rms - np.sqrt(max(rms_si**2 - mean_d, 0.0)) * MM_PER_M)
    return CrossValidation(k, int(seed) if isinstance(seed, (int, np.integer)) else 0, fold,
                           errors, rms, float(se_ms / (2 * rms)), tuple(fold_rms),
                           floor * MM_PER_M, tuple(coverage_warnings(poses, fold_of_pose,
                                                                     mset.joint_names)),
                           basis, bias, gross)
