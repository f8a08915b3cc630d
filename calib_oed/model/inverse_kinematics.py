r"""Inverse kinematics of a serial arm: closed-loop (CLIK) Gauss-Newton on SE(3), from a seed.

For a target :math:`T^\star_{W,E}` of the TCP frame :math:`E` (the tool frame
:math:`F` times a fixed tool offset :math:`T_{F,E}`) and a seed :math:`q_0`, the
iteration (Pinocchio's CLIK scheme, damped least squares on the frame's SE(3)
error, see the Pinocchio documentation "Inverse kinematics (clik)") is

.. math::

    e_k = \log_6\!\big(T_{W,E}(q_k)^{-1} T^\star_{W,E}\big), \qquad
    J_k = J_{\log_6}\!\big(T^{\star -1}_{W,E}\,T_{W,E}(q_k)\big)\,{}^{E}J_E(q_k),

    q_{k+1} = q_k + J_k^\top (J_k J_k^\top + \lambda^2 I)^{-1} D e_k,

:math:`{}^{E}J_E = \mathrm{Ad}_{T_{F,E}^{-1}}\,{}^{F}J_F` the frame Jacobian in
:math:`E` (``pin.LOCAL``), twists (linear, angular) [m, rad]. A step is taken only if
it lowers the error, else :math:`\lambda` grows tenfold (Levenberg-Marquardt);
after a taken step it falls back tenfold to its floor (default 1e-9, in the
scaled units below), so away from singularities the step is Newton's and
convergence is quadratic; steps are capped at ``max_step`` (0.2 rad). With more joints than 6 the step is the least-norm one, so the
solution stays next to the seed. The error norm is :math:`\lVert D e\rVert` with
:math:`D = \mathrm{diag}(1/L, 1/L, 1/L, 1, 1, 1)` and :math:`L` the arm's
characteristic length (:func:`characteristic_length`), so 1 mm at a 1 m arm
weighs as 1 mrad.

**Singularity measure.** :math:`\sigma_{min}` is the smallest singular value of
:math:`D\,{}^{E}J_E` [1] at the solution: a pose correction :math:`\varepsilon`
(scaled as above) needs a joint correction up to
:math:`\lVert\varepsilon\rVert/\sigma_{min}` [rad]. Near a singularity
(:math:`\sigma_{min} \to 0`) the solution moves far along the singular
direction or does not converge; callers name such targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ShapeError
from calib_oed.model.robot import Robot


def characteristic_length(robot: Robot) -> float:
    r""":math:`L` [m]: the sum of the joint placements' translations and the tool frame's offset.

    The length of the arm stretched out: the scale that makes a pose error's
    translation comparable to its rotation (1 rad of a joint near the base
    moves the TCP by about :math:`L`).
    """
    model = robot.model
    length = sum(float(np.linalg.norm(model.jointPlacements[i].translation))
                 for i in range(1, model.njoints))
    length += float(np.linalg.norm(model.frames[robot.tool_frame_id].placement.translation))
    return max(length, 1e-3)


@dataclass(frozen=True)
class IkSettings:
    """Settings of :func:`solve_ik`.

    Attributes:
        tolerance: Stop when :math:`\\lVert D e\\rVert` is below this [1] (1e-11: 1e-11 rad,
            or 1e-11 L m); a target that does not reach it is not converged.
        max_iterations: Iterations per target.
        damping: Smallest :math:`\\lambda` [1] of the damped least-squares step.
        max_step: Largest step :math:`\\lVert q_{k+1} - q_k\\rVert` [rad].
    """

    tolerance: float = 1e-11
    max_iterations: int = 50
    damping: float = 1e-9
    max_step: float = 0.2


@dataclass(frozen=True, eq=False)
class IkSolution:
    """Solutions of :func:`solve_ik` for n targets.

    Attributes:
        q: Joint values (n, nq) [rad or m].
        error: :math:`\\lVert D e\\rVert` at the end [1] (n,).
        position_error: Translation part of :math:`e`, :math:`\\lVert e_{1:3}\\rVert` [m] (n,).
        converged: ``error <= tolerance`` (n,).
        iterations: Iterations used (n,).
        sigma_min: Smallest singular value of :math:`D\\,{}^{E}J_E` at ``q`` [1] (n,).
    """

    q: np.ndarray
    error: np.ndarray
    position_error: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    sigma_min: np.ndarray


class TcpKinematics:
    """Forward kinematics, Jacobian and IK of a robot's TCP frame :math:`E = F\\,T_{F,E}`.

    Args:
        robot: The arm; its ``model`` (nominal or calibrated) is used as is.
        tool: :math:`T_{F,E}`, the TCP in the tool frame; None: the tool frame itself.
        length: :math:`L` [m]; None: :func:`characteristic_length` of ``robot``.
    """

    def __init__(self, robot: Robot, tool: pin.SE3 | None = None, length: float | None = None):
        self.robot = robot
        self.model = robot.model
        self.data = self.model.createData()
        self.frame = robot.tool_frame_id
        self.tool = pin.SE3.Identity() if tool is None else pin.SE3(tool)
        self._ad_tool_inv = self.tool.inverse().toActionMatrix()
        self.length = characteristic_length(robot) if length is None else float(length)
        self.scale = np.r_[np.full(3, 1.0 / self.length), np.ones(3)]

    def compute_pose(self, q: np.ndarray) -> pin.SE3:
        """:math:`T_{W,E}(q)` of one configuration (nq,)."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.frame] * self.tool

    def compute_jacobian(self, q: np.ndarray) -> tuple[pin.SE3, np.ndarray]:
        """:math:`T_{W,E}(q)` and :math:`{}^{E}J_E(q)` (6, nq), twists (linear, angular)."""
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacement(self.model, self.data, self.frame)
        jac = pin.getFrameJacobian(self.model, self.data, self.frame, pin.LOCAL)
        return self.data.oMf[self.frame] * self.tool, self._ad_tool_inv @ jac

    def compute_error(self, q: np.ndarray, target: pin.SE3) -> np.ndarray:
        """:math:`e = \\log_6(T_{W,E}(q)^{-1} T^\\star)` (6,)."""
        return pin.log6(self.compute_pose(q).actInv(target)).vector

    def compute_error_jacobian(self, q: np.ndarray, target: pin.SE3) -> tuple[np.ndarray, np.ndarray]:
        """:math:`e` (6,) and :math:`D J` (6, nq) of the module docstring at ``q``."""
        pose, jac = self.compute_jacobian(q)
        err = pin.log6(pose.actInv(target)).vector
        return err, self.scale[:, None] * (pin.Jlog6(target.actInv(pose)) @ jac)

    def solve(self, target: pin.SE3, seed: np.ndarray, settings: IkSettings) -> tuple[np.ndarray, float, float, int]:
        """One target: (q, scaled error, position error [m], iterations); the same iteration as
        :func:`solve_ik`, written for one target (a program's targets solved one after another)."""
        q = np.array(seed, dtype=float)
        lam, eye, scale = settings.damping, np.eye(6), self.scale
        err = self.compute_error(q, target)
        norm = float(np.linalg.norm(scale * err))
        j = None
        for it in range(settings.max_iterations):
            if norm <= settings.tolerance:
                return q, norm, float(np.linalg.norm(err[:3])), it
            if j is None:
                j = self.compute_error_jacobian(q, target)[1]
            step = j.T @ np.linalg.solve(j @ j.T + lam * lam * eye, scale * err)
            size = float(np.linalg.norm(step))
            if size > settings.max_step:
                step *= settings.max_step / size
            err_try = self.compute_error(q + step, target)
            norm_try = float(np.linalg.norm(scale * err_try))
            if norm_try < norm:
                q, err, norm, j = q + step, err_try, norm_try, None
                lam = max(lam / 10.0, settings.damping)
            else:
                lam = max(lam * 10.0, 1e-6)
        return q, norm, float(np.linalg.norm(err[:3])), settings.max_iterations


def _levenberg_marquardt(kin: TcpKinematics, targets, seeds: np.ndarray, settings: IkSettings):
    """The iteration of the module docstring for all targets at once: (q, e, iterations).

    The joints are single-coordinate (``nq = nv``, :class:`~calib_oed.model.robot.Robot`), so
    ``pin.integrate`` is an addition; the 6x6 systems are solved together.
    """
    n, nq = seeds.shape
    q = seeds.copy()
    err = np.array([kin.compute_error(q[i], targets[i]) for i in range(n)])
    norm = np.linalg.norm(err * kin.scale, axis=1)
    lam = np.full(n, settings.damping)
    jac = np.zeros((n, 6, nq))
    stale = np.ones(n, bool)
    iters = np.full(n, settings.max_iterations)
    for it in range(settings.max_iterations):
        done = norm <= settings.tolerance
        iters[done & (iters == settings.max_iterations)] = it
        active = np.flatnonzero(~done)
        if active.size == 0:
            break
        for i in active[stale[active]]:
            jac[i] = kin.compute_error_jacobian(q[i], targets[i])[1]
        j = jac[active]
        lhs = j @ j.transpose(0, 2, 1) + (lam[active] ** 2)[:, None, None] * np.eye(6)
        step = (j.transpose(0, 2, 1) @ np.linalg.solve(lhs, (err[active] * kin.scale)[:, :, None]))[:, :, 0]
        size = np.linalg.norm(step, axis=1)
        step *= np.minimum(1.0, settings.max_step / np.maximum(size, 1e-300))[:, None]
        q_try = q[active] + step
        err_try = np.array([kin.compute_error(q_try[k], targets[i]) for k, i in enumerate(active)])
        norm_try = np.linalg.norm(err_try * kin.scale, axis=1)
        better = norm_try < norm[active]
        good, bad = active[better], active[~better]
        q[good], err[good], norm[good] = q_try[better], err_try[better], norm_try[better]
        stale[good], stale[bad] = True, False
        lam[good] = np.maximum(lam[good] / 10.0, settings.damping)     # back towards Gauss-Newton
        lam[bad] = np.maximum(lam[bad] * 10.0, 1e-6)                   # damp more (Levenberg-Marquardt)
    return q, err, iters


def solve_ik(kin: TcpKinematics, targets, seeds: np.ndarray, settings: IkSettings | None = None) -> IkSolution:
    """Solve :math:`T_{W,E}(q) = T^\\star` for every target from its seed (module docstring).

    Args:
        kin: The kinematics (robot model and TCP).
        targets: n :class:`pinocchio.SE3` targets :math:`T^\\star_{W,E}`.
        seeds: (n, nq) start configurations (the branch is the seed's).
        settings: Tolerance, iterations, damping.
    """
    settings = settings or IkSettings()
    seeds = kin.robot.check_configurations(seeds, "seeds")
    targets = list(targets)
    if len(targets) != len(seeds):
        raise ShapeError("targets", f"({len(seeds)},) poses, one per seed", (len(targets),))
    q, err, iters = _levenberg_marquardt(kin, targets, seeds, settings)
    error = np.linalg.norm(err * kin.scale, axis=1)
    jac = np.array([kin.scale[:, None] * kin.compute_jacobian(row)[1] for row in q])
    sig = np.linalg.svd(jac, compute_uv=False)[:, -1] if len(q) else np.zeros(0)
    return IkSolution(q, error, np.linalg.norm(err[:, :3], axis=1), error <= settings.tolerance, iters, sig)


__all__ = ["IkSettings", "IkSolution", "TcpKinematics", "characteristic_length", "solve_ik"]
