"""The robot model: what the robot is, before anything is measured.

Owns robot loading (URDF into Pinocchio) and the robot registry, the
KUKA-class URDF generator and the paper's notional arms, batched tool
kinematics with their first and second derivatives, joint-space paths, the
parameter space (tracker pose, reflector offsets, perturbation frames of the
joints, optional joint compliances), gravity compliance, and the gauge rule
(which parameters the data can fix). It may import only
:mod:`calib_oed.exceptions` and :mod:`calib_oed.units`.
"""
