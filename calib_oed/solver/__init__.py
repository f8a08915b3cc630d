"""The generic SQP: nonlinear programs with bounds and inequality rows.

Owns the SQP iteration and its globalisation, the QP subproblem (ProxQP), and
the settings and result records. It knows nothing of robots: a problem is
anything with the ``compute_*`` methods the SQP calls. It may import only
:mod:`calib_oed.exceptions`.
"""
