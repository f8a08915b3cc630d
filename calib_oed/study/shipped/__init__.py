"""Shipped study configurations (``<name>.yaml``), loaded by name with
:func:`calib_oed.study.loader.load_study_config`; the schema is in
:mod:`calib_oed.study.loader` and ``docs/study.md``."""
