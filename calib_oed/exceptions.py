"""Exceptions raised by calib_oed.

Every error a user can cause derives from :class:`CalibOedError`. Each one
carries the offending data and, where there is a finite set of valid choices,
lists them, so that the message alone says what to fix.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def _choices(values: Iterable[str], limit: int = 40) -> str:
    values = list(values)
    shown = ", ".join(repr(v) for v in values[:limit])
    if len(values) > limit:
        shown += f", ... ({len(values) - limit} more)"
    return shown


class CalibOedError(Exception):
    """Base class of all calib_oed errors."""


class _UnknownName(CalibOedError):
    """A name that is not among ``valid``; the subclass's ``template`` says what the name is
    (``{name}`` and ``{choices}`` filled in).

    Attributes:
        name: The name that was asked for.
        valid: The valid names.
    """

    template = "unknown name {name!r}; valid names are: {choices}"

    def __init__(self, name: str, valid: Sequence[str]):
        self.name = name
        self.valid = list(valid)
        super().__init__(self.template.format(name=name, choices=_choices(self.valid)))


class _ValueNotMet(CalibOedError, ValueError):
    """An argument or setting ``what`` whose ``value`` does not meet ``requirement``; the
    subclass's ``template`` says whose (``{what}``, ``{value!r}``, ``{requirement}``).

    Attributes:
        what: The offending argument or setting (also as ``name``).
        value: The value given.
        valid: The valid choices, where there are few (listed in the message when
            ``list_choices``).
    """

    template = "{what} = {value!r}: {requirement}"
    list_choices = True

    def __init__(self, what: str, value, requirement: str, valid: Sequence[str] | None = None):
        self.what = self.name = what
        self.value = value
        self.valid = list(valid) if valid is not None else None
        choices = f"; valid choices are: {_choices(self.valid)}" if self.valid and self.list_choices else ""
        super().__init__(self.template.format(what=what, value=value, requirement=requirement) + choices)


class _FileKeyError(CalibOedError):
    """A file's key that is missing, malformed or inconsistent.

    Attributes:
        key: Dotted path of the offending key, or ``None`` for problems with the file
            as a whole.
        source: The file, if any.
    """

    def __init__(self, message: str, key: str | None = None, source: str | None = None):
        self.key = key
        self.source = source
        where = f"{source}: " if source else ""
        at = f"{key}: " if key else ""
        super().__init__(f"{where}{at}{message}")


class RobotLoadError(CalibOedError):
    """A robot description could not be loaded (missing file, malformed URDF)."""


class UnknownRobotError(_UnknownName, RobotLoadError):
    """A robot name matches no shipped or example-robot-data robot.

    Attributes:
        name: The name that was asked for.
        valid: The names that can be loaded.
    """

    template = ("unknown robot {name!r}; valid robot names are: {choices} "
                "(or pass the path of a URDF file)")


class UnknownFrameError(_UnknownName):
    """A frame name is not in the robot model.

    Attributes:
        name: The frame that was asked for.
        valid: The frames of the model.
    """

    template = "unknown frame {name!r}; the model has the frames: {choices}"


class UnknownJointError(_UnknownName):
    """A joint name is not among the robot's actuated joints."""

    template = "unknown joint {name!r}; the robot's joints are: {choices}"


class UnsupportedModelError(RobotLoadError):
    """The URDF is valid but not a model calib_oed can calibrate.

    Raised for kinematic trees that are not a serial chain up to the tool
    frame, and for joints whose configuration is not one real number per
    degree of freedom (continuous joints, mimic joints on the chain).
    """


class ShapeError(CalibOedError, ValueError):
    """An array has the wrong shape.

    Attributes:
        what: Name of the argument.
        expected: Expected shape, as text (``"(n, 6)"``).
        got: Shape received.
    """

    def __init__(self, what: str, expected: str, got: tuple[int, ...]):
        self.what = what
        self.expected = expected
        self.got = tuple(got)
        super().__init__(f"{what}: expected an array of shape {expected}, got shape {self.got}")


class NonFiniteError(CalibOedError, ValueError):
    """An input array holds NaN or infinite values."""

    def __init__(self, what: str, indices: Sequence[int] | None = None):
        self.what = what
        self.indices = list(indices) if indices is not None else []
        where = f" (at flat indices {self.indices[:10]})" if self.indices else ""
        super().__init__(f"{what}: contains NaN or infinite values{where}")


class JointLimitError(CalibOedError, ValueError):
    """Joint limits are inconsistent (lower above upper, non-finite)."""


class SceneError(_FileKeyError):
    """A scene file is missing, malformed or inconsistent.

    Attributes:
        key: Dotted path of the offending key (``"tracker.position"``), or
            ``None`` for problems with the file as a whole.
        source: The file the scene came from, if any.
    """


class UnknownSceneError(_UnknownName, SceneError):
    """A scene name matches no shipped scene and no file."""

    template = ("unknown scene {name!r}: no such file and no shipped scene of that name; "
                "shipped scenes are: {choices}")


class ParameterError(CalibOedError, ValueError):
    """A parameter vector or parameter name is invalid."""


class UnknownParameterError(_UnknownName, ParameterError):
    """A parameter name is not in the parameter space."""

    template = "unknown parameter {name!r}; parameters are: {choices}"


class NotIdentifiableError(CalibOedError):
    """A requested set of parameters cannot be identified from the design.

    Attributes:
        names: The parameters that are not identifiable.
    """

    def __init__(self, names: Sequence[str], detail: str = ""):
        self.names = list(names)
        extra = f" ({detail})" if detail else ""
        super().__init__(f"parameters not identifiable from this design: {_choices(self.names)}{extra}")


class MeasurementFileError(CalibOedError):
    """A measurement file has bad rows or a bad header; nothing was read.

    Attributes:
        source: The file (or ``"<string>"``).
        problems: ``(row, message)`` pairs; ``row`` is the 1-based line number
            in the file (the header is line 1), or ``None`` for the file as a whole.
    """

    def __init__(self, source: str, problems: Sequence[tuple[int | None, str]], kind: str = "measurement file"):
        self.source = source
        self.problems = list(problems)
        self.kind = kind
        lines = [f"line {row}: {msg}" if row is not None else msg for row, msg in self.problems[:20]]
        if len(self.problems) == 1:  # one problem, one line
            super().__init__(f"{source}: {kind}, nothing was read: {lines[0]}")
            return
        more = f"\n  ... ({len(self.problems) - 20} more)" if len(self.problems) > 20 else ""
        super().__init__(
            f"{source}: {len(self.problems)} problem(s) in the {kind}, nothing was read:\n  "
            + "\n  ".join(lines)
            + more
        )


class IdentificationFileError(CalibOedError, ValueError):
    """An identification JSON that does not hold what the joint-space model-error prior needs
    (``--prior-from``, ``robot.model_error.from``; the message says what)."""


class ExportError(CalibOedError):
    """A result could not be written (bad output path, unsupported URDF content)."""


class UnknownLinkError(_UnknownName):
    """A link name is not in the robot model (capsule tables, excluded pairs)."""

    template = "unknown link {name!r}; the robot's links are: {choices}"


class SamplingError(CalibOedError):
    """Too few feasible configurations were found (the constraints may be too tight)."""


class NotPositiveDefiniteError(CalibOedError, ValueError):
    """A covariance matrix is not symmetric positive definite.

    Attributes:
        what: Which matrix.
        eigenvalues: Its eigenvalues (of the symmetric part), ascending.
    """

    def __init__(self, what: str, eigenvalues: Sequence[float], detail: str = ""):
        self.what = what
        self.eigenvalues = list(map(float, eigenvalues))
        extra = f" ({detail})" if detail else ""
        super().__init__(
            f"{what}: a confidence ellipsoid needs a symmetric positive definite covariance; "
            f"eigenvalues are {self.eigenvalues}{extra}"
        )


class ConfidenceLevelError(CalibOedError, ValueError):
    """A confidence level is not a number strictly between 0 and 1."""

    def __init__(self, level):
        self.level = level
        super().__init__(
            f"confidence level must be strictly between 0 and 1 (e.g. 0.95), got {level!r}"
        )


class UnknownCriterionError(_UnknownName):
    """A design criterion name is not one calib_oed knows.

    Attributes:
        name: The name that was asked for.
        valid: The criterion names that can be made.
    """

    template = "unknown criterion {name!r}; valid criterion names are: {choices}"


class SQPSettingsError(_ValueNotMet):
    """An :class:`SQPSettings` value is invalid (``name`` the setting, ``valid`` its choices where there are few)."""

    template = "SQPSettings.{what} = {value!r}: {requirement}"
    list_choices = False


class SQPProblemError(CalibOedError, ValueError):
    """The problem given to :func:`~calib_oed.solver.sqp.solve_sqp` is inconsistent (``lb > ub``).

    Attributes:
        indices: The offending variable indices.
    """

    def __init__(self, message: str, indices=()):
        self.indices = list(indices)
        super().__init__(message)


class ViewerSettingError(_ValueNotMet):
    """A setting of the meshcat view (:mod:`calib_oed.viz.viewer`) is invalid (``name`` the setting, ``valid`` its choices where there are few)."""

    template = "viewer setting {what} = {value!r}: {requirement}"
    list_choices = False


class StudyConfigError(_FileKeyError):
    """A study configuration (:mod:`calib_oed.study.config`) is missing, malformed or inconsistent.

    Attributes:
        key: Dotted path of the offending key (``"sqp.max_iterations"``), or
            ``None`` for problems with the file as a whole.
        source: The file the configuration came from, if any.
    """


class StudyLockError(CalibOedError):
    """Another process is running a study into the same output folder.

    Attributes:
        folder: The output folder.
        owner: What the lock file says about the other process (its pid), or ``""``.
    """

    def __init__(self, folder, owner: str = ""):
        self.folder = str(folder)
        self.owner = owner
        super().__init__(
            f"the study folder {self.folder} is in use by another study process"
            f"{f' ({owner})' if owner else ''}; wait for it to finish, or give another -o folder"
        )


class StudyResumeError(CalibOedError):
    """A study output folder holds a case result computed with other settings.

    Attributes:
        path: The case file.
        differences: The settings that differ, ``"key: stored -> configured"``.
    """

    def __init__(self, path, differences: Sequence[str]):
        self.path = str(path)
        self.differences = list(differences)
        super().__init__(
            f"{self.path} was computed with other settings ({'; '.join(self.differences) or 'unknown'}); "
            "use another output folder, or delete the case files to recompute them"
        )


class OptionalDependencyError(CalibOedError, ImportError):
    """A feature needs an optional dependency that is not installed.

    Attributes:
        package: The missing import.
        extra: The calib_oed extra that installs it (``pip install 'calib_oed[<extra>]'``).
    """

    def __init__(self, feature: str, package: str, extra: str):
        self.package = package
        self.extra = extra
        super().__init__(f"{feature} needs {package}, which is not installed: "
                         f"pip install 'calib_oed[{extra}]'")


class CertificateError(_ValueNotMet):
    """An optimality certificate (:mod:`calib_oed.oed.certificate`) cannot be computed as asked.

    Attributes:
        what: The offending argument (``"criterion"``, ``"pool"``, ...).
        value: The value given.
        valid: The valid choices, where there are few.
    """

    template = "certificate: {what} = {value!r}: {requirement}"


class SequentialError(_ValueNotMet):
    """A sequential calibration (:mod:`calib_oed.oed.sequential`) cannot run as asked.

    Attributes:
        what: The offending argument (``"target_sigma_mm"``, ``"batch"``, ...).
        value: The value given.
    """

    template = "sequential design: {what} = {value!r}: {requirement}"


class AggregateError(CalibOedError, ValueError):
    """A KPI aggregate that does not exist, or that does not apply to the criterion asked for.

    Attributes:
        aggregate: The aggregate asked for.
        valid: The aggregates that apply (``mean``, ``max``).
    """

    def __init__(self, aggregate, valid: Sequence[str], why: str = ""):
        self.aggregate = aggregate
        self.valid = list(valid)
        super().__init__(why or f"unknown KPI aggregate {aggregate!r}; valid aggregates are: "
                         f"{_choices(self.valid)}")


class DesignError(_ValueNotMet):
    """A design (:func:`calib_oed.oed.design.design`) cannot be computed as asked.

    Attributes:
        what: The offending argument (``"start"``, ``"pool"``, ``"replicates"``, ``"n"``, ...).
        value: The value given.
        valid: The valid choices, where there are few.
    """

    template = "design: {what} = {value!r}: {requirement}"


class DesignMemoryError(DesignError, MemoryError):
    """A design too large for this machine's memory, found before anything is allocated.

    Attributes:
        needed_bytes: Estimated peak memory of the design [bytes].
        available_bytes: Memory available now [bytes].
        largest_n: Largest number of poses that fits.
        share: Largest share of the available memory a design may use.
    """

    def __init__(self, n: int, needed_bytes: float, available_bytes: float, largest_n: int,
                 share: float):
        self.needed_bytes = float(needed_bytes)
        self.available_bytes = float(available_bytes)
        self.largest_n = int(largest_n)
        CalibOedError.__init__(
            self, f"design: n = {n} poses needs about {needed_bytes / 2**30:.1f} GiB of memory, more than "
            f"{100 * share:.0f} % of the {available_bytes / 2**30:.1f} GiB available; the largest n that fits is about "
            f"{largest_n} (or design in batches with `calib-oed sequential`)")
        self.what, self.value, self.valid = "n", n, None


class OutputPathError(ExportError):
    """An output path that cannot be written, found before any work is done."""

    def __init__(self, option: str, path, problem: str):
        self.option, self.path = option, str(path)
        super().__init__(f"{option} {self.path}: {problem}")


class CalibOedNote(UserWarning):
    """Not an error, worth knowing (repeated rows, poses that collide); the CLI prints one line."""


class LinkFitSettingsError(_ValueNotMet):
    """A setting of the link-geometry fit is out of range (the message says the valid range)."""

    template = "link fit: {what} = {value!r}: {requirement}"


class ProgramError(_ValueNotMet):
    """A measurement program (:mod:`calib_oed.program`) cannot be built as asked (a bad
    setting or format, a pose in collision, a move no plan connects); names the valid choices."""

    template = "program: {what} = {value!r}: {requirement}"


class DataSanityError(CalibOedError):
    """Measured data that do not fit the scene: the tracker registration residual is implausible.

    Attributes:
        source: The measurement file.
        rms_mm: RMS registration residual [mm].
        limit_mm: The plausibility limit [mm].
        causes: ``(description, evidence)`` of the likely mistakes, best first.
    """

    def __init__(self, source, rms_mm: float, limit_mm: float, causes, hint: str = ""):
        self.source, self.rms_mm, self.limit_mm = source, float(rms_mm), float(limit_mm)
        self.causes = list(causes)
        likely = ("; likely: " + "; ".join(f"{d} ({e})" for d, e in self.causes) if self.causes else
                  "; no single mistake explains it: check the scene, the units and the joint order")
        super().__init__(f"{source}: the data do not fit the scene: registration RMS {self.rms_mm:.3g} mm "
                         f"above the plausibility limit {self.limit_mm:.3g} mm{hint}{likely}")


class CompensationError(CalibOedError, ValueError):
    """A program or calibration cannot be compensated as asked (mismatched robots, an unsupported
    calibration or target); the message names what to fix."""


class ParameterTableError(CalibOedError, ValueError):
    """A parameter table (DH, modified DH, Hayati) cannot be computed, read or written as asked;
    the message names the problem and the valid choices."""


class InputFileError(CalibOedError):
    """An input file calib_oed refuses to read: not a regular file, too large, YAML with a
    duplicate key or aliases that expand beyond a bound (the message names the limit)."""

    def __init__(self, source, problem: str):
        self.source, self.problem = str(source), problem
        super().__init__(f"{self.source}: {problem}")
