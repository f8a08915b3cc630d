r"""Exact designs by point exchange (Fedorov 1972; Mitchell 1974, DETMAX).

A design picks :math:`n` distinct candidates out of :math:`N` (feasible
poses); candidate :math:`c` contributes the block
:math:`F_c \in \mathbb{R}^{d \times n_p}` of the weighted, unit-scaled
sensitivity (rows dimensionless, columns in 1/mm or 1/mrad) and the design's
information is

.. math::
    M(\xi) = M_0 + \sum_{j \in \xi} F_j^\top F_j \in \mathbb{R}^{n_p \times n_p},

with :math:`M_0` optional prior information. :func:`exchange_design`
minimises a :class:`~calib_oed.oed.criterion_base.Criterion` :math:`\phi(M(\xi))` over
designs by single-point swaps, as in the exchange algorithms of Fedorov (1972,
*Theory of Optimal Experiments*, ch. 3), Mitchell (1974, *Technometrics*
16(2), DETMAX) and the "modified Fedorov" ordering of Cook & Nachtsheim
(1980, *Technometrics* 22(3)): a sweep visits the design points in order;
for point :math:`i` it forms :math:`M_{-i} = M(\xi) - F_i^\top F_i`,
evaluates :math:`\phi(M_{-i} + F_c^\top F_c)` for every candidate :math:`c`
not in the design, and swaps :math:`i` for the best one if that lowers
:math:`\phi` by more than ``rtol`` :math:`\cdot|\phi|`. Sweeps repeat until
one makes no swap (a local optimum: no single swap improves) or
``max_sweeps``. The result depends on the start; run a few seeds and keep
the best.

For the A-criterion (any weight :math:`W = R^\top R`), the D-criterion and
:math:`O_1` the candidates are ranked by rank-:math:`d` updates: with
:math:`A = M_{-i}^{-1}` and :math:`S_c = F_c A F_c^\top` (d, d),

.. math::
    \mathrm{tr}\big(W (M_{-i} + F_c^\top F_c)^{-1}\big)
    = \mathrm{tr}(W A) - \mathrm{tr}\big((I + S_c)^{-1} B_c B_c^\top\big),
    \quad B_c = F_c A R^\top,

    \log\det(M_{-i} + F_c^\top F_c) = \log\det M_{-i} + \log\det(I + S_c),

computed for all :math:`N` candidates from one product
:math:`[F_1; \dots; F_N] A` of shape (N d, n_p). Other criteria evaluate
:meth:`~calib_oed.oed.criterion_base.Criterion.compute_values` on the stacked
:math:`M_{-i} + F_c^\top F_c` in chunks. Either way :math:`M_{-i}` is summed
afresh (no drift from repeated updates), and the chosen swap's value is
recomputed exactly before it is accepted, so the values recorded are exact
and never increase.
"""

from __future__ import annotations

import operator
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from calib_oed.exceptions import NonFiniteError, NotIdentifiableError, ShapeError
from calib_oed.oed.criteria import ACriterion, DCriterion
from calib_oed.oed.criterion_base import Criterion, _forward_substitution, as_information
from calib_oed.oed.observability import ObservabilityIndex

#: Random starts drawn before giving up on a nonsingular one.
START_TRIES = 20
#: Bytes of stacked (n_p, n_p) matrices evaluated at once on the generic path.
CHUNK_BYTES = 1 << 25
#: :math:`\lambda_{\min}/\lambda_{\max}` of :math:`M_{-i}` below which the rank-update path defers to the generic one.
RANK_UPDATE_RCOND = 1e-10
METHODS = ("auto", "rank", "generic")


@dataclass(frozen=True, eq=False)
class ExchangeResult:
    """Outcome of :func:`exchange_design`.

    Attributes:
        indices: Candidate indices of the design, (n,), in design order, read-only.
        value: Criterion value of the final design.
        initial_value: Criterion value of the start design.
        history: Value after each sweep.
        n_sweeps: Sweeps made (the last one made no swap if ``converged``).
        n_exchanges: Swaps made in all.
        converged: A sweep made no swap, so no single swap improves the design
            by more than ``rtol``; ``False`` if ``max_sweeps`` stopped it.
        time: Wall time [s].
        criterion: Name of the criterion.
        method: ``"rank"`` (rank-d updates) or ``"generic"`` (batched values).
    """

    indices: np.ndarray
    value: float
    initial_value: float
    history: tuple[float, ...]
    n_sweeps: int
    n_exchanges: int
    converged: bool
    time: float
    criterion: str = ""
    method: str = ""

    def __post_init__(self):
        idx = np.array(self.indices, dtype=np.intp)
        idx.setflags(write=False)
        object.__setattr__(self, "indices", idx)
        object.__setattr__(self, "history", tuple(float(v) for v in self.history))

    def check(self, blocks, criterion: Criterion, prior=None, rtol: float = 1e-8) -> bool:
        """Whether the design is valid and its value, recomputed from scratch, matches :attr:`value`.

        Returns ``False`` for duplicate indices, a singular information
        matrix or a value off by more than ``rtol`` relative; raises for
        blocks the indices do not fit.
        """
        blocks = check_blocks(blocks)
        if self.indices.size and (self.indices.min() < 0 or self.indices.max() >= blocks.shape[0]):
            raise ValueError(f"indices out of range for {blocks.shape[0]} candidates")
        if np.unique(self.indices).size != self.indices.size:
            return False
        try:
            value = criterion.compute_value(information_matrix(blocks, self.indices, prior))
        except NotIdentifiableError:
            return False
        return bool(abs(value - self.value) <= rtol * max(abs(value), abs(self.value)))

    def to_dict(self) -> dict:
        """Plain JSON-serialisable dictionary."""
        return {
            "indices": self.indices.tolist(),
            "value": self.value,
            "initial_value": self.initial_value,
            "history": list(self.history),
            "n_sweeps": self.n_sweeps,
            "n_exchanges": self.n_exchanges,
            "converged": self.converged,
            "time": self.time,
            "criterion": self.criterion,
            "method": self.method,
        }


# -------------------------------------------------------------- validation
def check_blocks(blocks, what: str = "blocks") -> np.ndarray:
    """Per-candidate information rows as a float array (N, d, n_p), finite, no empty axis.

    Raises:
        ShapeError, NonFiniteError: naming ``what``.
    """
    b = np.asarray(blocks, dtype=float)
    if b.ndim != 3 or 0 in b.shape:
        raise ShapeError(what, "(N, d, n_p) with N, d, n_p >= 1", b.shape)
    if not np.all(np.isfinite(b)):
        raise NonFiniteError(what, np.flatnonzero(~np.isfinite(b)).tolist())
    return b


def _check_prior(prior, n_p: int) -> np.ndarray:
    if prior is None:
        return np.zeros((n_p, n_p))
    m = as_information(prior, "prior")
    if m.shape != (n_p, n_p):
        raise ShapeError("prior", f"({n_p}, {n_p})", m.shape)
    lam = np.linalg.eigvalsh(m)
    if lam[0] < -1e-10 * max(abs(lam[-1]), np.finfo(float).tiny):
        raise ValueError(f"prior must be positive semidefinite; smallest eigenvalue {lam[0]:.3g}")
    return m


def _check_start(start, n: int, n_cand: int) -> np.ndarray:
    s = np.asarray(start)
    if s.shape != (n,):
        raise ShapeError("start", f"({n},)", s.shape)
    if s.size and not np.issubdtype(s.dtype, np.integer):
        raise ValueError(f"start must hold integer candidate indices, got dtype {s.dtype}")
    s = s.astype(np.intp)
    if np.any((s < 0) | (s >= n_cand)):
        raise ValueError(f"start indices must be in [0, {n_cand}), got {s[(s < 0) | (s >= n_cand)].tolist()}")
    values, counts = np.unique(s, return_counts=True)
    if np.any(counts > 1):
        raise ValueError(f"start indices must be distinct; repeated: {values[counts > 1].tolist()}")
    return s.copy()


def information_matrix(blocks, indices, prior=None) -> np.ndarray:
    r""":math:`M = M_0 + \sum_{j} F_j^\top F_j` over ``indices`` of ``blocks`` (N, d, n_p)."""
    blocks = check_blocks(blocks)
    n_p = blocks.shape[2]
    f = blocks[np.asarray(indices, dtype=np.intp)].reshape(-1, n_p)
    m = f.T @ f + _check_prior(prior, n_p)
    return 0.5 * (m + m.T)


# ---------------------------------------------------------------- ranking
def _rank_kind(criterion: Criterion, method: str) -> str | None:
    """``"trace"``, ``"logdet"`` or ``None`` (generic) for this criterion and method."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    kind = None
    if type(criterion) is ACriterion:
        kind = "trace"
    elif type(criterion) is DCriterion or (type(criterion) is ObservabilityIndex and criterion.k == 1):
        kind = "logdet"
    if method == "rank" and kind is None:
        raise ValueError(
            f"method='rank' needs the A-criterion, the D-criterion or O1; got {criterion.name!r} "
            "(use method='auto' or 'generic')"
        )
    return None if method == "generic" else kind


def _small_cholesky(k: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of a stack (N, d, d) of SPD matrices, vectorised over N (d small)."""
    low = np.zeros_like(k)
    for j in range(k.shape[-1]):
        low[:, j, j] = np.sqrt(k[:, j, j] - np.sum(low[:, j, :j] ** 2, axis=1))
        for i in range(j + 1, k.shape[-1]):
            dot = np.sum(low[:, i, :j] * low[:, j, :j], axis=1)
            low[:, i, j] = (k[:, i, j] - dot) / low[:, j, j]
    return low


def _rank_update_scores(kind, criterion, m_minus, blocks, flat, blocks_t=None):
    r"""Scores of all candidates (lower is better) by rank-d updates, or ``None`` if M_{-i} is ill-conditioned.

    ``"trace"``: the A-criterion value of :math:`M_{-i} + F_c^\top F_c`;
    ``"logdet"``: :math:`-\log\det(I + S_c)`, which orders candidates as
    :math:`\log\det C` does. ``blocks_t``: :math:`F_c^\top` (N, n_p, d),
    contiguous (one batched product for every :math:`S_c`; computed if None).
    """
    lam = np.linalg.eigvalsh(m_minus)
    if lam[0] <= RANK_UPDATE_RCOND * lam[-1]:
        return None
    n_cand, d, n_p = blocks.shape
    low = scipy.linalg.cholesky(m_minus, lower=True, check_finite=False)
    a = scipy.linalg.cho_solve((low, True), np.eye(n_p), check_finite=False)  # A = M_{-i}^{-1}
    root = criterion.root if kind == "trace" else np.zeros((0, n_p))
    # one product for the rows of F_c A and of B_c = F_c A R^T: (N d, n_p + r)
    fab = flat @ np.hstack([a, a @ root.T])
    fa3 = fab[:, :n_p].reshape(n_cand, d, n_p)
    if blocks_t is None:
        blocks_t = np.ascontiguousarray(blocks.transpose(0, 2, 1))
    s_c = np.matmul(fa3, blocks_t)  # S_c = F_c A F_c^T, (N, d, d), symmetric up to rounding
    i_s = 0.5 * (s_c + s_c.transpose(0, 2, 1)) + np.eye(d)  # I + S_c (eigenvalues >= 1)
    chol = _small_cholesky(i_s)
    if kind == "logdet":
        return -2.0 * np.sum(np.log(np.diagonal(chol, axis1=1, axis2=2)), axis=1)
    b = fab[:, n_p:].reshape(n_cand, d, root.shape[0])
    reduction = np.sum(_forward_substitution(chol, b) ** 2, axis=(1, 2))  # tr((I + S_c)^-1 B_c B_c^T)
    return (np.sum((root @ a) * root) - reduction) / criterion.dim


def _generic_scores(criterion, m_minus, blocks, pool):
    """Exact values of ``m_minus + F_c^T F_c`` for candidates ``pool``, in chunks; +inf if singular."""
    n_p = blocks.shape[2]
    chunk = max(1, CHUNK_BYTES // (8 * n_p * n_p))
    out = np.empty(pool.size)
    for start in range(0, pool.size, chunk):
        f = blocks[pool[start:start + chunk]]
        infos = m_minus + np.matmul(f.transpose(0, 2, 1), f)
        out[start:start + chunk] = criterion.compute_values(infos, singular="inf")
    return out


def _start_design(info_of, criterion, start, rng, n: int, n_cand: int) -> tuple[np.ndarray, float]:
    """The start design (given, or random until nonsingular) and its value."""
    if start is not None:
        design = _check_start(start, n, n_cand)
        try:
            return design, criterion.compute_value(info_of(design))
        except NotIdentifiableError as err:
            raise NotIdentifiableError(err.names, "the start design is singular") from err
    gen = np.random.default_rng(rng)
    for _ in range(START_TRIES):
        design = gen.choice(n_cand, size=n, replace=False).astype(np.intp)
        try:
            return design, criterion.compute_value(info_of(design))
        except NotIdentifiableError as err:
            last = err
    raise NotIdentifiableError(
        last.names,
        f"{START_TRIES} random designs of {n} of the {n_cand} candidates were all singular; "
        "the candidates may not identify these columns, or n is too small",
    ) from last


# ----------------------------------------------------------------- driver
def exchange_design(
    blocks,
    n: int,
    criterion: Criterion,
    *,
    start=None,
    rng=None,
    max_sweeps: int = 100,
    rtol: float = 1e-10,
    prior=None,
    method: str = "auto",
) -> ExchangeResult:
    r"""A locally optimal design of ``n`` distinct candidates by point exchange.

    Args:
        blocks: Candidate blocks :math:`F_c`, (N, d, n_p), rows dimensionless,
            columns in 1/mm or 1/mrad.
        n: Design size, :math:`1 \le n \le N`.
        criterion: The criterion to minimise.
        start: Initial candidate indices, (n,), distinct. Default: drawn at
            random (up to :data:`START_TRIES` times until :math:`M` is nonsingular).
        rng: Seed or ``numpy.random.Generator`` for the random start, the only
            source of randomness.
        max_sweeps: Most sweeps over the design points.
        rtol: A swap must lower the value by more than ``rtol * |value|``.
        prior: Prior information :math:`M_0`, (n_p, n_p), symmetric PSD.
        method: ``"auto"`` (rank-d updates where available), ``"rank"``
            (require them) or ``"generic"`` (batched values for every criterion).

    Returns:
        The :class:`ExchangeResult`.

    Raises:
        ShapeError, NonFiniteError, ValueError: invalid input (``n > N``, too
            few rows :math:`n d < n_p` without a prior, repeated start indices).
        NotIdentifiableError: the start design (given, or every random try) is singular.
    """
    t0 = time.perf_counter()
    blocks = check_blocks(blocks)
    n_cand, d, n_p = blocks.shape
    n = operator.index(n)
    if not 1 <= n <= n_cand:
        raise ValueError(f"n = {n}: the design size must be between 1 and the number of candidates N = {n_cand}")
    if prior is None and n * d < n_p:
        raise ValueError(
            f"n = {n} poses give n*d = {n * d} rows for n_p = {n_p} parameters: "
            f"the information matrix is singular; take n >= {-(-n_p // d)} or pass a prior"
        )
    prior = _check_prior(prior, n_p)
    if not isinstance(criterion, Criterion):
        raise TypeError(f"criterion must be a calib_oed.oed.criterion_base.Criterion, got {type(criterion).__name__}")
    max_sweeps = operator.index(max_sweeps)
    if max_sweeps < 0 or not np.isfinite(rtol) or rtol < 0:
        raise ValueError(f"need max_sweeps >= 0 and a finite rtol >= 0, got {max_sweeps}, {rtol}")
    kind = _rank_kind(criterion, method)
    flat = blocks.reshape(n_cand * d, n_p)
    blocks_t = np.ascontiguousarray(blocks.transpose(0, 2, 1)) if kind is not None else None

    def info_of(idx):
        f = blocks[idx].reshape(-1, n_p)
        m = prior + f.T @ f
        return 0.5 * (m + m.T)

    design, value = _start_design(info_of, criterion, start, rng, n, n_cand)
    initial_value = float(value)
    history, n_exchanges, converged = [], 0, False
    in_design = np.zeros(n_cand, dtype=bool)
    in_design[design] = True
    for _ in range(max_sweeps):
        swaps = 0
        for i in range(n):
            m_minus = info_of(np.delete(design, i))
            scores = (None if kind is None else
                      _rank_update_scores(kind, criterion, m_minus, blocks, flat, blocks_t))
            if scores is None:
                pool = np.flatnonzero(~in_design)
                scores = np.full(n_cand, np.inf)
                scores[pool] = _generic_scores(criterion, m_minus, blocks, pool)
            scores[in_design] = np.inf
            best = int(np.argmin(scores)) if scores.size else -1
            if best < 0 or not np.isfinite(scores[best]):
                continue
            try:
                new = criterion.compute_value(m_minus + blocks[best].T @ blocks[best])
            except NotIdentifiableError:
                continue
            if new < value - rtol * abs(value):
                in_design[design[i]], in_design[best] = False, True
                design[i], value = best, new
                swaps += 1
        history.append(float(value))
        n_exchanges += swaps
        if swaps == 0:
            converged = True
            break
    return ExchangeResult(
        indices=design,
        value=float(value),
        initial_value=initial_value,
        history=tuple(history),
        n_sweeps=len(history),
        n_exchanges=n_exchanges,
        converged=converged,
        time=time.perf_counter() - t0,
        criterion=criterion.name,
        method="generic" if kind is None else "rank",
    )
