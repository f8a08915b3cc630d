"""Shipped study configurations (``<name>.yaml``), loaded by name with
:func:`calib_oed.study.config.load_study_config`; the schema is in
:mod:`calib_oed.study.config` and ``docs/study.md``."""
