"""Studies: the paper's comparisons over many robots and criteria, run as one job.

Owns the study configuration (records in ``config``, read by ``loader``;
shipped configs in ``shipped/``), one case's computation (``case``), the
result records (``results``), the runner (cases in parallel, cached by
content hash) and the report (tables and figures). It may import every
package but :mod:`calib_oed.cli`.
"""
