r"""Measurement-model contract and the state the models evaluate at.

A measurement model maps parameters :math:`p` and a configuration :math:`q`
to a measured vector :math:`h(p, q) \in \mathbb{R}^{d}` with independent
Gaussian noise of standard deviation :math:`\sigma \in \mathbb{R}^d`. It
implements three ``compute_*`` methods, each batched over the n
configurations of a :class:`SetupState`:

- :meth:`MeasurementModel.compute_values` :math:`h`, (n, d);
- :meth:`MeasurementModel.compute_param_jacobian` :math:`\partial h/\partial p`, (n, d, n_p);
- :meth:`MeasurementModel.compute_config_jacobian` :math:`\partial h/\partial q`, (n, d, nv).

Stacking several models into :math:`F_1 = \Sigma^{-1}\,\partial h/\partial p`
is done by :mod:`calib_oed.measurement.sensitivity`.

With joint compliance modelled (:mod:`calib_oed.model.compliance`) the kinematics
of the state run at :math:`q_{eff} = q + c\circ\tau_g(q)`; a model computes its
derivatives along :math:`q_{eff}` and in the right perturbations
:math:`\epsilon` as before, and hands them to the state's chain helpers
(:meth:`SetupState.fill_joint_columns`, :meth:`SetupState.chain_config`,
:meth:`SetupState.finish_param_config`), which add the compliance columns and
the factor :math:`D = \partial q_{eff}/\partial q`. Joint gains and coupling
ratios (:mod:`calib_oed.model.joint_map`) go the same way: :math:`q_{eff}` gains
:math:`\sum_m\theta_m E_m q`, their columns are :math:`(\partial h/\partial q_{eff})\,E_m q`.
Without compliance and gains they change nothing.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pinocchio as pin

from calib_oed.measurement.noise_contract import NoiseContract
from calib_oed.model.joint_map import config_chain_term, effective_configurations, parameter_columns
from calib_oed.model.kinematics import (
    ToolKinematics,
    compute_tool_kinematics,
    cross,
    jacobian_config_derivative,
    regressor_config_derivative,
    skew,
)
from calib_oed.model.parameters import ParameterSpace


@dataclass(frozen=True, eq=False)
class SetupState:
    r"""Robot and sensor at parameters ``p``, evaluated at configurations ``q``.

    Attributes:
        space: The parameter layout.
        p: Parameter vector (n_p,).
        kin: Tool kinematics of the perturbed robot.
        tracker: :math:`T_{W,T}(p)`, tracker frame in world.
        reflectors: Reflector offsets in the tool frame, (k, 3) [m].
        joint_jr: Right Jacobians of the joint perturbations (n_j, 6, 6), or
            None when all joint perturbations are zero.
        torque: Gravity torques :math:`\tau_g(q)` at the commanded
            configurations (n, nv) [N·m] when compliance is modelled, else None;
            ``kin`` is then evaluated at :math:`q_{eff} = q + c\circ\tau_g`.
        torque_q: :math:`\partial\tau_g/\partial q` (n, nv, nv), with
            compliance and ``jacobian=True``, else None.
        gain_columns: :math:`[E_1 q, \dots]` at the commanded configurations
            (n, nv, n_gains) when joint gains or couplings are identified, else None.
    """

    space: ParameterSpace
    p: np.ndarray
    kin: ToolKinematics
    tracker: pin.SE3
    reflectors: np.ndarray
    joint_jr: np.ndarray | None
    torque: np.ndarray | None = None
    torque_q: np.ndarray | None = None
    gain_columns: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.kin.n

    @property
    def rigid(self) -> bool:
        """True when the kinematics run at the commanded q (no compliance, no gains)."""
        return self.torque is None and self.gain_columns is None

    @cached_property
    def regressor_q(self) -> np.ndarray:
        r""":math:`\partial K/\partial q` (n, 6, 6 n_j, nv), computed once per state for all models
        (:func:`calib_oed.model.kinematics.regressor_config_derivative`)."""
        return regressor_config_derivative(self.kin)

    @cached_property
    def jacobian_q(self) -> np.ndarray:
        r""":math:`\partial J/\partial q` (n, 6, nv, nv), once per state (second-order models)."""
        return jacobian_config_derivative(self.kin)

    def joint_param_sensitivity(self, d_eps: np.ndarray) -> np.ndarray:
        r"""Chain rule from right perturbations :math:`\epsilon_i` to parameters :math:`\delta_i`.

        ``d_eps`` is (n, d, 6 n_j); returns :math:`d_\epsilon \cdot \mathrm{blkdiag}(J_r(\delta_i))`.
        """
        if self.joint_jr is None:
            return d_eps
        n, d, _ = d_eps.shape
        blocks = d_eps.reshape(n, d, -1, 6)
        return np.einsum("ndjk,jkl->ndjl", blocks, self.joint_jr).reshape(n, d, -1)

    # ------------------------------------------------------------ compliance
    @cached_property
    def config_chain(self) -> np.ndarray | None:
        r""":math:`D = \partial q_{eff}/\partial q = I + \mathrm{diag}(c)\,\partial\tau_g/\partial q`,
        (n, nv, nv), or None without compliance and gains (:math:`D = I`); gains add
        :math:`\sum_m\theta_m E_m`."""
        if self.rigid:
            return None
        if self.torque is None:
            d = np.broadcast_to(np.eye(self.kin.q.shape[1]), (self.n,) + (self.kin.q.shape[1],) * 2)
        else:
            if self.torque_q is None:
                raise ValueError("configuration derivatives with compliance need the gravity torque "
                                 "derivatives: evaluate the set-up with jacobian=True")
            c = self.p[self.space.compliance_slice]
            d = np.eye(self.torque.shape[1])[None] + c[None, :, None] * self.torque_q
        if self.gain_columns is not None:
            d = d + config_chain_term(self.space.gain_basis, self.p[self.space.gain_slice])[None]
        return d

    def chain_config(self, d_qeff: np.ndarray) -> np.ndarray:
        r"""A derivative along :math:`q_{eff}` (last axis nv) to one along :math:`q`: times :math:`D`."""
        d = self.config_chain
        if d is None:
            return d_qeff
        return np.einsum("n...l,nlk->n...k", d_qeff, d)

    def _along_axes(self, d_eps: np.ndarray) -> np.ndarray:
        r""":math:`(\partial h/\partial\epsilon_i)\,S_i` per joint: (n, d, 6 n_j, ...) -> (n, d, n_j, ...)."""
        n, d = d_eps.shape[:2]
        blocks = d_eps.reshape(n, d, -1, 6, *d_eps.shape[3:])
        return np.einsum("ndjk...,jk->ndj...", blocks, self.space.joint_axes)

    def fill_joint_columns(self, out: np.ndarray, d_eps: np.ndarray) -> None:
        r"""Write the joint (and compliance) columns of :math:`\partial h/\partial p` into ``out``.

        ``d_eps`` (n, d, 6 n_j) is :math:`\partial h/\partial\epsilon`; joint
        columns :meth:`joint_param_sensitivity`, compliance columns
        :math:`(\partial h/\partial\epsilon_i)\,S_i\,\tau_i = (\partial h/\partial q_{eff,i})\,\tau_i`,
        gain and coupling columns :math:`(\partial h/\partial q_{eff})\,E_m q`.
        """
        space = self.space
        out[..., space.joints_slice] = self.joint_param_sensitivity(d_eps)
        if self.torque is not None:
            out[..., space.compliance_slice] = self._along_axes(d_eps) * self.torque[:, None, :]
        if self.gain_columns is not None:
            out[..., space.gain_slice] = np.einsum("ndi,nim->ndm", self._along_axes(d_eps),
                                                   self.gain_columns)

    def finish_param_config(self, mixed: np.ndarray, d_eps: np.ndarray,
                            d_eps_q: np.ndarray) -> np.ndarray:
        r"""Mixed derivative along :math:`q_{eff}` -> along :math:`q`, with the compliance columns.

        ``mixed`` (n, d, n_p, nv) holds the geometric columns differentiated
        along :math:`q_{eff}`; ``d_eps`` (n, d, 6 n_j) is
        :math:`\partial h/\partial\epsilon` and ``d_eps_q`` (n, d, 6 n_j, nv)
        its derivative along :math:`q_{eff}`. Geometric columns times :math:`D`;
        compliance column ``i`` along :math:`q_k`:
        :math:`\sum_l H_{il} D_{lk}\,\tau_i + (\partial h/\partial q_{eff,i})\,\partial\tau_i/\partial q_k`
        with :math:`H_{il} = (\partial^2 h/\partial\epsilon_i\,\partial q_{eff,l})\,S_i`;
        gain or coupling column ``m`` along :math:`q_k`:
        :math:`\sum_{il} H_{il} D_{lk}\,(E_m q)_i + \sum_i (\partial h/\partial q_{eff,i})\,(E_m)_{ik}`.
        """
        if self.rigid:
            return mixed
        d = self.config_chain
        out = np.einsum("ndpl,nlk->ndpk", mixed, d)
        hess = np.einsum("ndil,nlk->ndik", self._along_axes(d_eps_q), d)
        first = self._along_axes(d_eps)  # (n, d, nj)
        if self.torque is not None:
            out[:, :, self.space.compliance_slice, :] = (
                hess * self.torque[:, None, :, None] + first[:, :, :, None] * self.torque_q[:, None]
            )
        if self.gain_columns is not None:
            out[:, :, self.space.gain_slice, :] = (
                np.einsum("ndik,nim->ndmk", hess, self.gain_columns)
                + np.einsum("ndi,imk->ndmk", first, self.space.gain_basis)
            )
        return out

    def tracker_point_sensitivity(self, y: np.ndarray) -> np.ndarray:
        r"""Derivative of :math:`y = T_{W,T}(\delta_T)^{-1} x` w.r.t. :math:`\delta_T`.

        For a right perturbation :math:`\epsilon = (v, \omega)` of the tracker
        frame, :math:`dy = -v + [y]_\times \omega`; then times :math:`J_r(\delta_T)`.
        ``y`` is (n, 3) in the tracker frame; returns (n, 3, 6).
        """
        n = y.shape[0]
        out = np.zeros((n, 3, 6))
        out[:, :, :3] = -np.eye(3)
        out[:, :, 3:] = skew(y)
        delta = self.p[self.space.tracker_slice]
        if np.any(delta):
            out = out @ pin.Jexp6(delta)
        return out

    def reflector_offset(self, j: int) -> np.ndarray:
        """Offset :math:`c_j(p)` of reflector ``j`` in the tool frame (3,) [m]."""
        if not 0 <= j < self.space.n_reflectors:
            raise ValueError(f"reflector {j}: the set-up has reflectors "
                             f"0..{self.space.n_reflectors - 1}")
        return self.reflectors[j]

    def tool_point(self, offset: np.ndarray, frame: str) -> np.ndarray:
        r"""A tool point in the ``"world"`` or ``"tracker"`` frame, (n, 3) [m].

        World: :math:`x = t + R c`; tracker: :math:`T_{W,T}^{-1} x`.
        """
        x = self.kin.points(offset)
        if frame == "tracker":
            x = (x - self.tracker.translation) @ self.tracker.rotation
        return x

    def tool_point_param_jacobian(
        self, offset: np.ndarray, frame: str, reflector: int | None = None
    ) -> np.ndarray:
        r""":math:`\partial x/\partial p` of :meth:`tool_point`, (n, 3, n_p).

        Joint columns :math:`R[I\; -[c]_\times]K\,J_r`; with ``reflector=j`` the
        point is :math:`c_j(p)` and its offset columns are :math:`R`; in the
        tracker frame every row is premultiplied by :math:`R_T^\top` and the
        tracker columns are :meth:`tracker_point_sensitivity`.
        """
        space = self.space
        out = np.zeros((self.n, 3, space.size))
        d_eps = self.kin.point_sensitivity(offset, "regressor")
        d_refl = self.kin.rotation
        if frame == "tracker":
            rt = self.tracker.rotation
            d_eps = rt.T @ d_eps
            d_refl = rt.T @ d_refl
            out[:, :, space.tracker_slice] = self.tracker_point_sensitivity(
                self.tool_point(offset, frame)
            )
        if reflector is not None:
            out[:, :, space.reflector_slice(reflector)] = d_refl
        self.fill_joint_columns(out, d_eps)
        return out

    def joint_param_config_sensitivity(self, d_eps_q: np.ndarray) -> np.ndarray:
        """:meth:`joint_param_sensitivity` for a derivative along q, (n, d, 6 n_j, nv)."""
        if self.joint_jr is None:
            return d_eps_q
        moved = np.moveaxis(d_eps_q, 3, 1)  # (n, nv, d, 6 n_j)
        n, nv, d, c = moved.shape
        out = self.joint_param_sensitivity(moved.reshape(n * nv, d, c)).reshape(n, nv, d, c)
        return np.moveaxis(out, 1, 3)

    def tool_point_param_config_jacobian(
        self, offset: np.ndarray, frame: str, reflector: int | None = None
    ) -> np.ndarray:
        r"""Mixed derivative :math:`\partial^2 x/\partial p\,\partial q` of :meth:`tool_point`, (n, 3, n_p, nv).

        With :math:`L(X) = X_v + X_\omega \times c` column-wise (so that
        :math:`\partial x/\partial\epsilon = R\,L(K)`), :math:`\omega_k` the
        LOCAL angular part of Jacobian column ``k`` and :math:`\partial K/\partial q_k`
        from :func:`calib_oed.model.kinematics.regressor_config_derivative`:

        .. math::
            \frac{\partial^2 x}{\partial\epsilon\,\partial q_k}
                = R\,\big([\omega_k]_\times L(K) + L(\partial K/\partial q_k)\big),\qquad
            \frac{\partial^2 x}{\partial c_j\,\partial q_k} = R\,[\omega_k]_\times .

        In the tracker frame every row is premultiplied by :math:`R_T^\top`, and
        the tracker columns :math:`[-I\;\; [y]_\times]\,J_r(\delta_T)` give
        :math:`[\,0\;\; [\partial y/\partial q_k]_\times]\,J_r(\delta_T)`
        (``docs/derivations.md`` §11).
        """
        space = self.space
        kin = self.kin
        c = np.asarray(offset, dtype=float)
        reg_q = self.regressor_q  # (n, 6, 6nj, nv)
        omega = kin.jacobian[:, 3:, :]  # (n, 3, nv) local
        n, nv = self.n, omega.shape[2]
        out = np.zeros((n, 3, space.size, nv))
        lk = kin.regressor[:, :3, :] + cross(kin.regressor[:, 3:, :], c[None, :, None], axis=1)
        lkq = reg_q[:, :3] + cross(reg_q[:, 3:], c[None, :, None, None], axis=1)
        # [w_k]x L(K): cross of omega (n,3,1,nv) with L(K) (n,3,6nj,1)
        d_eps = cross(omega[:, :, None, :], lk[:, :, :, None], axis=1) + lkq
        rot = kin.rotation
        if frame == "tracker":
            rot = self.tracker.rotation.T @ rot
        d_eps = np.einsum("nab,nbcq->nacq", rot, d_eps)
        out[:, :, space.joints_slice, :] = self.joint_param_config_sensitivity(d_eps)
        first = None
        if not self.rigid:  # dh/d(eps) before the J_r chain, for the compliance and gain columns
            first = np.einsum("nab,nbc->nac", rot, lk)
        if reflector is not None:
            # R [w_k]x e_m = R (w_k x e_m)
            refl = np.einsum("nab,nbmq->namq", rot, skew(np.moveaxis(omega, 1, 2)).transpose(0, 2, 3, 1))
            out[:, :, space.reflector_slice(reflector), :] = refl
        if frame == "tracker":
            dy = self._tool_point_qeff_jacobian(c, frame)  # (n, 3, nv) along q_eff
            trk = np.zeros((n, nv, 3, 6))
            trk[:, :, :, 3:] = skew(np.moveaxis(dy, 1, 2))
            delta = self.p[space.tracker_slice]
            if np.any(delta):
                trk = trk @ pin.Jexp6(delta)
            out[:, :, space.tracker_slice, :] = np.moveaxis(trk, 1, 3)
        if first is None:
            return out
        return self.finish_param_config(out, first, d_eps)

    def _tool_point_qeff_jacobian(self, offset: np.ndarray, frame: str) -> np.ndarray:
        d_q = self.kin.point_sensitivity(offset, "jacobian")
        return self.tracker.rotation.T @ d_q if frame == "tracker" else d_q

    def tool_point_config_jacobian(self, offset: np.ndarray, frame: str) -> np.ndarray:
        r""":math:`\partial x/\partial q` of :meth:`tool_point`, (n, 3, nv) (times :math:`D` with compliance)."""
        return self.chain_config(self._tool_point_qeff_jacobian(offset, frame))


def evaluate_setup(
    space: ParameterSpace,
    p: np.ndarray | None,
    q: np.ndarray,
    *,
    regressor: bool = True,
    jacobian: bool = True,
) -> SetupState:
    r"""Perturb the robot and the sensor by ``p`` and run the kinematics at ``q`` (n, nq).

    With compliance modelled the kinematics run at :math:`q + c\circ\tau_g(q)`,
    and the state carries :math:`\tau_g` (and its derivative when ``jacobian``);
    with joint gains they run at :math:`q_{eff}` plus :math:`\sum_m\theta_m E_m q`
    (:mod:`calib_oed.model.joint_map`), :math:`\tau_g` still at the commanded q.
    """
    p = space.check(p)
    q = space.robot.check_configurations(q)
    model = space.perturbed_model(p)
    torque = torque_q = gains = None
    q_cmd = q
    if space.gravity is not None:
        torque = space.gravity.torques(q)
        torque_q = space.gravity.torque_derivatives(q) if jacobian else None
        q = q + p[space.compliance_slice] * torque
    if space.gain_basis is not None:
        gains = parameter_columns(q_cmd, space.gain_basis)
        q = q + (effective_configurations(q_cmd, space.gain_basis, p[space.gain_slice]) - q_cmd)
    kin = compute_tool_kinematics(
        model, space.robot.tool_frame_id, q, regressor=regressor, jacobian=jacobian
    )
    return SetupState(
        space=space,
        p=p,
        kin=kin,
        tracker=space.tracker_placement(p),
        reflectors=space.reflector_offsets(p),
        joint_jr=space.joint_exp_jacobians(p),
        torque=torque,
        torque_q=torque_q,
        gain_columns=gains,
    )


class MeasurementModel(NoiseContract, abc.ABC):
    """A measurement of the robot by an external sensor (see module docstring).

    Args:
        sigma: Noise standard deviation per measured component, shape (d,)
            or scalar, in the SI units of the components.
    """

    #: Dimension d of one measurement.
    dim: int = 0
    #: Names of the d components.
    labels: tuple[str, ...] = ()
    #: SI units of the d components.
    units: tuple[str, ...] = ()

    def __init__(self, sigma: float | np.ndarray):
        s = np.broadcast_to(np.asarray(sigma, dtype=float), (self.dim,)).copy()
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ValueError(f"{type(self).__name__}: sigma must be positive and finite, got {s}")
        s.setflags(write=False)
        self.sigma = s

    @property
    def name(self) -> str:
        """Short name used in reports."""
        return type(self).__name__

    @abc.abstractmethod
    def compute_values(self, state: SetupState) -> np.ndarray:
        """Model response :math:`h(p, q)`, (n, d)."""

    @abc.abstractmethod
    def compute_param_jacobian(self, state: SetupState) -> np.ndarray:
        r""":math:`\partial h / \partial p`, (n, d, n_p)."""

    @abc.abstractmethod
    def compute_config_jacobian(self, state: SetupState) -> np.ndarray:
        r""":math:`\partial h / \partial q`, (n, d, nv)."""

    def compute_param_config_jacobian(self, state: SetupState) -> np.ndarray:
        r"""Mixed derivative :math:`\partial^2 h / \partial p\,\partial q`, (n, d, n_p, nv).

        Row block j of :math:`F_1` depends on :math:`q_j` alone, so this is all
        the criterion gradient of the design optimisation needs. ``state``
        must carry both the regressor and the Jacobian.
        """
        raise NotImplementedError(
            f"{type(self).__name__} does not provide the mixed derivative needed for design "
            "optimisation; implement compute_param_config_jacobian"
        )

    def compute_param_config_hessian(self, state: SetupState) -> np.ndarray | None:
        r""":math:`\partial^3 h/\partial p\,\partial q_k\,\partial q_l`, (n, d, n_p, nv, nv), or None.

        For the exact design Hessian (``docs/derivations.md`` §13). None if the model lacks
        it or with compliance modelled (needs :math:`\partial^2\tau_g/\partial q^2`).
        """
        return None
