r"""Joint gains and coupling ratios: optional parameters on the joint values (encoder scale).

A joint's encoder scale may differ from its nominal value by a small relative
error :math:`g_i` (a gear ratio or an encoder resolution that is slightly off),
and a mechanical coupling between two axes (FANUC's J2/J3 linkage, the
``couplings`` of the scene's ``controller`` block, :mod:`calib_oed.model.controller`)
may have a ratio that differs from its nominal value by :math:`\kappa_{jf}`.
With these parameters the kinematics run at

.. math::
    q_{eff} = q + \sum_m \theta_m\,E_m\,q, \qquad
    E_m = e_i e_i^\top \ \text{(gain of joint } i), \quad
    E_m = e_j e_f^\top \ \text{(coupling of joint } j \text{ to joint } f),

i.e. :math:`q_{eff,i} = (1 + g_i)\,q_i` and :math:`q_{eff,j} \mathrel{+}= \kappa_{jf}\,q_f`,
with :math:`q` the commanded URDF joint values [rad] (prismatic [m]),
:math:`\theta` the block's parameters, all nominal 0. Everything is linear in
:math:`q`: :math:`\partial q_{eff}/\partial\theta_m = E_m q` and
:math:`\partial q_{eff}/\partial q = I + \sum_m \theta_m E_m`, both exact.

**Against a joint offset.** A gain moves joint ``i`` by :math:`g_i q_i`, an offset by a
constant: the two are separable only when the data spread :math:`q_i` (the gauge
rule decides, ``docs/conventions.md``). A gain on the controller side,
:math:`q_i = s_i k_i (1 + g_i) c_i + o_i` (:mod:`calib_oed.model.controller`), moves
:math:`q_i` by :math:`g_i (q_i - o_i)`: the same as here up to the constant
:math:`-g_i o_i`, which the joint's zero offset absorbs. Likewise a coupling ratio
error :math:`\delta r` of the controller's coupling :math:`(j, f, r)` moves
:math:`q_j` by :math:`s_j k_j\,\delta r\,c_f`; for a source joint without a coupling
of its own this is :math:`\kappa_{jf} (q_f - o_f)` with
:math:`\kappa_{jf} = \delta r\,s_j k_j/(s_f k_f)`, so :math:`\delta r = \kappa_{jf}\,s_f k_f/(s_j k_j)`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ParameterError


@dataclass(frozen=True)
class JointGains:
    """Which joint gains and coupling ratios are identified (joints numbered 1..n).

    Attributes:
        joints: Joints with a gain parameter ``joint{i}.gain``, ascending.
        couplings: ``(joint, source)`` pairs with a ratio parameter
            ``joint{joint}.coupling{source}``: :math:`q_{eff,joint} \\mathrel{+}= \\kappa\\,q_{source}`.
    """

    joints: tuple[int, ...] = ()
    couplings: tuple[tuple[int, int], ...] = ()

    def __post_init__(self):
        joints = tuple(sorted({int(i) for i in self.joints}))
        couplings = tuple((int(j), int(f)) for j, f in self.couplings)
        if len(set(couplings)) != len(couplings):
            raise ParameterError(f"coupling pairs must be distinct, got {list(couplings)}")
        if any(j == f for j, f in couplings):
            raise ParameterError(f"a coupling needs two different joints, got {list(couplings)}")
        if not joints and not couplings:
            raise ParameterError("joint gains: name at least one joint or one coupling")
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "couplings", couplings)

    @classmethod
    def all_joints(cls, n: int, couplings=()) -> JointGains:
        """A gain for every joint 1..n, and the given couplings."""
        return cls(tuple(range(1, n + 1)), tuple(couplings))

    @property
    def size(self) -> int:
        """Number of parameters: one per gain, one per coupling."""
        return len(self.joints) + len(self.couplings)

    def check(self, n: int) -> None:
        """Raise :class:`ParameterError` unless every joint number is in 1..n."""
        used = list(self.joints) + [k for pair in self.couplings for k in pair]
        bad = [k for k in used if not 1 <= k <= n]
        if bad:
            raise ParameterError(f"joint gains: joint number(s) {bad} out of range; the robot has "
                                 f"joints 1..{n}")

    def basis(self, n: int) -> np.ndarray:
        r"""The matrices :math:`E_m` stacked as (n, size, n): ``[i, m, k]`` = :math:`(E_m)_{ik}`."""
        out = np.zeros((n, self.size, n))
        for m, i in enumerate(self.joints):
            out[i - 1, m, i - 1] = 1.0
        for m, (j, f) in enumerate(self.couplings, start=len(self.joints)):
            out[j - 1, m, f - 1] = 1.0
        out.setflags(write=False)
        return out


def effective_configurations(q: np.ndarray, basis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    r""":math:`q + \sum_m\theta_m E_m q` at every row of ``q`` (N, n) [rad]."""
    return q + q @ np.einsum("m,imk->ik", theta, basis).T


def parameter_columns(q: np.ndarray, basis: np.ndarray) -> np.ndarray:
    r""":math:`\partial q_{eff}/\partial\theta = [E_1 q, \dots]` at every row of ``q``, (N, n, size)."""
    return np.einsum("imk,Nk->Nim", basis, q)


def config_chain_term(basis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    r""":math:`\sum_m\theta_m E_m`, the block's part of :math:`\partial q_{eff}/\partial q`, (n, n)."""
    return np.einsum("m,imk->ik", theta, basis)
