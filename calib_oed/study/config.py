r"""Study configurations: which robots in which scenes, and how each case is designed.

A *study* is robots × scenes × criteria × collision settings × seeds. One
*case* is one robot in one scene; in every case :mod:`calib_oed.study.runner` runs
the heuristic designs of all ``heuristic_seeds`` and, for each ``collisions``
flag and each criterion, the SQP design from the same start. Configurations
are YAML files (shipped ones in ``calib_oed/study/shipped/``, see
:func:`study_names`)::

    version: 1
    name: kuka
    description: the paper's first study
    cases:
      robots:                                # (robot, scene) pairs
        - {robot: kr16, scene: fms_kr16}     # a shipped scene or a file
        - {robot: kr300, scene_template: fms_kr16}   # the template scaled for the arm
      notional: grid                         # the paper's 90 arms, or {lambdas: [..], mus: [..]} [mm]
      scene_template: fms_kr16               # scene of the notional arms, scaled per arm
    n: 60                                    # poses per design
    heuristic_seeds: [0, 1, 2, 3, 4]         # the heuristic baseline: the median over these
    criteria: [params, kpi]                  # C_p-optimal (state of the art) and KPI-optimal
    collisions: [true, false]                # with and without collision constraints
    start: heuristic                         # heuristic | exchange
    seed: 0                                  # seed of the start design
    sqp: {max_iterations: 80, time_limit: 30}   # per SQP run; time_limit [s] or null
    certificate: {pool: 3000, seed: 0, local_starts: 32}   # optional: KPI lower bound per case

Errors raise :class:`~calib_oed.exceptions.StudyConfigError` naming the
dotted key and the valid choices. Scaled scenes: :mod:`calib_oed.scene.scaling`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from calib_oed.exceptions import CalibOedError, StudyConfigError
from calib_oed.model.kuka import NOTIONAL_LAMBDAS, NOTIONAL_MUS
from calib_oed.model.registry import NOTIONAL_PATTERN
from calib_oed.oed.criteria import CRITERIA
from calib_oed.oed.design import DESIGN_SQP, STARTS
from calib_oed.scene.reader import load_scene, scene_names
from calib_oed.scene.records import Scene
from calib_oed.scene.scaling import kuka_dimensions, scaled_scene
from calib_oed.solver.sqp import SQPSettings

__all__ = ["CaseSpec", "CertificatePlan", "DesignPlan", "StudyCase", "StudyConfig", "load_study_config",
           "study_config_from_dict", "study_names"]

SUPPORTED_VERSIONS = (1,)
#: Version of the case computation; part of every case hash (bump when results change meaning).
CASE_FORMAT = "calib_oed study case v1"
DEFAULT_CRITERIA = ("params", "kpi")
DEFAULT_COLLISIONS = (True, False)
DEFAULT_HEURISTIC_SEEDS = tuple(range(10))
_TOP_REQUIRED = ("version", "name", "cases")
_TOP_OPTIONAL = ("description", "n", "heuristic_seeds", "criteria", "collisions", "start", "seed",
                 "sqp", "certificate")


@dataclass(frozen=True)
class CertificatePlan:
    """The optimality certificate of every case (:func:`calib_oed.oed.certificate.certify`, criterion ``kpi``).

    Attributes:
        pool: Random feasible candidates (the study's feasible designs are added).
        seed: Seed of the pool.
        local_starts: Starts of the local maximisation of the sensitivity
            off the pool (0: the bound is certified on the pool only).
    """

    pool: int = 3000
    seed: int = 0
    local_starts: int = 32

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class DesignPlan:
    """What is computed in every case of a study.

    Attributes:
        n: Poses per design.
        heuristic_seeds: Seeds of the heuristic designs (random feasible poses);
            the study reports their median.
        criteria: Criteria optimised (names of :data:`calib_oed.oed.criteria.CRITERIA`):
            ``params`` (A on :math:`C_p`, the state of the art), ``kpi`` (A on :math:`C_s`).
        collisions: Collision settings of the optimised designs: ``True`` (all
            constraints), ``False`` (joint limits and incidence only).
        start: ``"heuristic"`` or ``"exchange"`` (:func:`calib_oed.oed.design.design`).
        seed: Seed of the start design (the heuristic design of that seed).
        max_iterations: SQP iteration limit per design.
        time_limit: SQP wall-clock limit per design [s], or None.
        certificate: Certificate of each case, or None (no certificate).
    """

    n: int = 60
    heuristic_seeds: tuple[int, ...] = DEFAULT_HEURISTIC_SEEDS
    criteria: tuple[str, ...] = DEFAULT_CRITERIA
    collisions: tuple[bool, ...] = DEFAULT_COLLISIONS
    start: str = "heuristic"
    seed: int = 0
    max_iterations: int = DESIGN_SQP.max_iterations
    time_limit: float | None = None
    certificate: CertificatePlan | None = None

    def check(self) -> DesignPlan:
        """Raise :class:`StudyConfigError` on an invalid value; return self."""
        if not (isinstance(self.n, int) and self.n >= 1):
            raise StudyConfigError(f"expected an integer >= 1, got {self.n!r}", key="n")
        for key, values in (("heuristic_seeds", self.heuristic_seeds), ("criteria", self.criteria),
                            ("collisions", self.collisions)):
            if not values or len(set(values)) != len(values):
                raise StudyConfigError(f"expected a non-empty list without repeats, got "
                                       f"{list(values)!r}", key=key)
        bad = [c for c in self.criteria if c not in CRITERIA]
        if bad:
            raise StudyConfigError(f"unknown criterion {bad[0]!r}; valid criteria are: "
                                   f"{', '.join(CRITERIA)}", key="criteria")
        if self.start not in STARTS:
            raise StudyConfigError(f"expected one of {', '.join(STARTS)}, got {self.start!r}",
                                   key="start")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise StudyConfigError(f"expected an integer >= 1, got {self.max_iterations!r}",
                                   key="sqp.max_iterations")
        if self.time_limit is not None and not (math.isfinite(self.time_limit)
                                                and self.time_limit > 0):
            raise StudyConfigError(f"expected a number of seconds > 0 or null, got "
                                   f"{self.time_limit!r}", key="sqp.time_limit")
        return self

    def sqp_settings(self) -> SQPSettings:
        """:data:`calib_oed.oed.design.DESIGN_SQP` with this plan's limits."""
        limit = math.inf if self.time_limit is None else float(self.time_limit)
        return dataclasses.replace(DESIGN_SQP, max_iterations=self.max_iterations,
                                   time_limit=limit)

    def to_dict(self) -> dict:
        out = {"n": self.n, "heuristic_seeds": list(self.heuristic_seeds),
               "criteria": list(self.criteria), "collisions": list(self.collisions),
               "start": self.start, "seed": self.seed,
               "sqp": {"max_iterations": self.max_iterations, "time_limit": self.time_limit}}
        if self.certificate is not None:  # absent otherwise: the case hashes of older studies hold
            out["certificate"] = self.certificate.to_dict()
        return out


@dataclass(frozen=True)
class CaseSpec:
    """One robot in one scene.

    Attributes:
        case_id: ``<robot>-<scene>`` (``kr16-fms_kr16``) or, for a scaled scene,
            ``<robot>-scaled_<template>``; the case file's name.
        robot: Robot name (``kr16``, ``notional_l650_m600``, ...).
        scene: A shipped scene name or an absolute scene file path; None for a scaled scene.
        template: The scene scaled for the robot (:mod:`calib_oed.scene.scaling`), or None.
        lambda_mm: Upper-arm length λ of a notional arm [mm], else None.
        mu_mm: Forearm length μ of a notional arm [mm], else None.
        scene_digest: SHA-256 (16 hex digits) of the scene's (or template's) file text,
            so a resumed study notices an edited scene.
    """

    case_id: str
    robot: str
    scene: str | None = None
    template: str | None = None
    lambda_mm: int | None = None
    mu_mm: int | None = None
    scene_digest: str = ""

    def check(self) -> CaseSpec:
        if (self.scene is None) == (self.template is None):
            raise StudyConfigError(f"case {self.case_id!r}: expected exactly one of scene and "
                                   f"scene_template")
        return self

    @property
    def scene_label(self) -> str:
        """The scene as named in reports (a file's stem, or ``scaled <template>``)."""
        if self.template is not None:
            return f"{_label(self.template)} scaled"
        return _label(self.scene)

    def load_scene(self) -> Scene:
        """The case's scene (a scaled scene is built, validated like a file)."""
        if self.template is not None:
            return scaled_scene(self.robot, self.template)
        return load_scene(self.scene)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class StudyCase:
    """A case with the plan it runs: the unit of work of :func:`calib_oed.study.runner.run_case`."""

    spec: CaseSpec
    plan: DesignPlan

    @property
    def case_id(self) -> str:
        return self.spec.case_id

    def identity(self) -> dict:
        """What determines the case's results (the hash's input): no paths, no names."""
        spec = self.spec
        return {"format": CASE_FORMAT, "robot": spec.robot,
                "scene": None if spec.scene is None else _label(spec.scene),
                "template": None if spec.template is None else _label(spec.template),
                "scene_digest": spec.scene_digest, **self.plan.to_dict()}

    @property
    def config_hash(self) -> str:
        """SHA-256 (16 hex digits) of :meth:`identity`; stored in the case file."""
        text = json.dumps(self.identity(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        return {"spec": self.spec.to_dict(), "plan": self.plan.to_dict(),
                "config_hash": self.config_hash}


@dataclass(frozen=True)
class StudyConfig:
    """A study: its cases and the plan every case runs.

    Attributes:
        name: Study name.
        description: Free text.
        specs: The cases (robot, scene), in the order of the file.
        plan: What each case computes.
        source: The YAML file, or None.
        raw_cases: The ``cases:`` block as normalised (for :meth:`to_dict`).
    """

    name: str
    description: str
    specs: tuple[CaseSpec, ...]
    plan: DesignPlan
    source: str | None = None
    raw_cases: dict = dataclasses.field(default_factory=dict)

    def check(self) -> StudyConfig:
        if not self.specs:
            raise StudyConfigError("expected at least one case", key="cases", source=self.source)
        ids = [s.case_id for s in self.specs]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise StudyConfigError(f"the same case appears twice: {', '.join(dup)}", key="cases",
                                   source=self.source)
        for spec in self.specs:
            spec.check()
        self.plan.check()
        return self

    def cases(self) -> tuple[StudyCase, ...]:
        """Every case with the plan, in file order."""
        return tuple(StudyCase(spec, self.plan) for spec in self.specs)

    def to_dict(self) -> dict:
        """The configuration as YAML would state it (normalised)."""
        return {"version": 1, "name": self.name, "description": self.description,
                "cases": self.raw_cases, **self.plan.to_dict()}


def _label(scene: str) -> str:
    return Path(scene).stem if (os.sep in scene or scene.endswith((".yaml", ".yml"))) else scene


def study_names() -> list[str]:
    """Names of the shipped study configurations (``calib_oed/study/shipped/<name>.yaml``)."""
    folder = resources.files("calib_oed.study.shipped")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_study_config(name_or_path: str | os.PathLike) -> StudyConfig:
    """A shipped study configuration by name, or a configuration file by path.

    Raises:
        StudyConfigError: unknown name (lists the shipped studies), unreadable
            file, YAML error or invalid content.
    """
    text = os.fspath(name_or_path)
    if text in study_names():
        path = Path(str(resources.files("calib_oed.study.shipped").joinpath(f"{text}.yaml")))
    else:
        path = Path(text)
        if not path.is_file():
            raise StudyConfigError(f"no such file and no shipped study of that name; shipped "
                                   f"studies are: {', '.join(study_names())}", source=text)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise StudyConfigError(f"YAML syntax error{at}: {getattr(exc, 'problem', exc)}",
                               source=str(path)) from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise StudyConfigError(f"cannot read the study configuration ({exc})",
                               source=str(path)) from exc
    return study_config_from_dict(data, source=str(path))


def study_config_from_dict(data: Mapping[str, Any], source: str | None = None) -> StudyConfig:
    """Validate a parsed configuration (schema in the module docstring).

    Args:
        data: The parsed YAML.
        source: The file it came from: named in errors; relative scene paths
            resolve against its folder (default: the working directory).
    """
    return _Reader(source).config(data)


@cache
def _file_digest(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


class _Reader:
    """Key-by-key validation; errors name the dotted key and the valid choices."""

    def __init__(self, source: str | None):
        self.source = source
        self.folder = Path(source).parent if source else Path.cwd()

    def fail(self, key: str | None, message: str) -> StudyConfigError:
        return StudyConfigError(message, key=key, source=self.source)

    def mapping(self, value, key, required=(), optional=()) -> dict:
        valid = (*required, *optional)
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a mapping with keys {', '.join(valid)}, got {value!r}")
        where = f"{key}." if key else ""
        for k in value:
            if k not in valid:
                raise self.fail(f"{where}{k}", f"unknown key; valid keys of "
                                f"{repr(key) if key else 'the top level'} are: {', '.join(valid)}")
        for k in required:
            if k not in value:
                raise self.fail(f"{where}{k}", f"missing required key; required: "
                                f"{', '.join(required)}")
        return dict(value)

    def integer(self, value, key, minimum=0) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(key, f"expected an integer >= {minimum}, got {value!r}")
        return value

    def string(self, value, key) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(key, f"expected a non-empty string, got {value!r}")
        return value

    def items(self, value, key, check) -> tuple:
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"expected a non-empty list, got {value!r}")
        out = tuple(check(v, f"{key}[{i}]") for i, v in enumerate(value))
        if len(set(out)) != len(out):
            raise self.fail(key, f"repeated entries in {value!r}")
        return out

    def config(self, data) -> StudyConfig:
        top = self.mapping(data, None, _TOP_REQUIRED, _TOP_OPTIONAL)
        if isinstance(top["version"], bool) or top["version"] not in SUPPORTED_VERSIONS:
            raise self.fail("version", f"unsupported version {top['version']!r}; supported: "
                            f"{', '.join(map(str, SUPPORTED_VERSIONS))}")
        description = top.get("description", "")
        if not isinstance(description, str):
            raise self.fail("description", f"expected a string, got {description!r}")
        specs, raw = self.cases(top["cases"])
        plan = self.plan(top)
        return StudyConfig(self.string(top["name"], "name"), description.strip(), specs, plan,
                           self.source, raw).check()

    def plan(self, top: dict) -> DesignPlan:
        def criterion(v, key):
            if v not in CRITERIA:
                raise self.fail(key, f"unknown criterion {v!r}; valid criteria are: "
                                f"{', '.join(CRITERIA)}")
            return v

        def flag(v, key):
            if not isinstance(v, bool):
                raise self.fail(key, f"expected true (with collision constraints) or false "
                                f"(without), got {v!r}")
            return v

        start = top.get("start", "heuristic")
        if start not in STARTS:
            raise self.fail("start", f"expected one of {', '.join(STARTS)}, got {start!r}")
        sqp = self.mapping(top.get("sqp", {}), "sqp", (), ("max_iterations", "time_limit"))
        limit = sqp.get("time_limit")
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, float))
                                  or not math.isfinite(limit) or limit <= 0):
            raise self.fail("sqp.time_limit", f"expected a number of seconds > 0 or null, "
                            f"got {limit!r}")
        return DesignPlan(
            n=self.integer(top.get("n", 60), "n", 1),
            heuristic_seeds=self.items(top.get("heuristic_seeds", list(DEFAULT_HEURISTIC_SEEDS)),
                                       "heuristic_seeds", self.integer),
            criteria=self.items(top.get("criteria", list(DEFAULT_CRITERIA)), "criteria",
                                criterion),
            collisions=self.items(top.get("collisions", list(DEFAULT_COLLISIONS)), "collisions",
                                  flag),
            start=start,
            seed=self.integer(top.get("seed", 0), "seed"),
            max_iterations=self.integer(sqp.get("max_iterations", DESIGN_SQP.max_iterations),
                                        "sqp.max_iterations", 1),
            time_limit=None if limit is None else float(limit),
            certificate=self.certificate(top.get("certificate", False)),
        ).check()

    def certificate(self, value) -> CertificatePlan | None:
        if value is False or value is None:
            return None
        if value is True:
            return CertificatePlan()
        keys = tuple(f.name for f in dataclasses.fields(CertificatePlan))
        spec = self.mapping(value, "certificate", (), keys)
        default = CertificatePlan()
        return CertificatePlan(
            pool=self.integer(spec.get("pool", default.pool), "certificate.pool", 1),
            seed=self.integer(spec.get("seed", default.seed), "certificate.seed"),
            local_starts=self.integer(spec.get("local_starts", default.local_starts),
                                      "certificate.local_starts"))

    def cases(self, value) -> tuple[tuple[CaseSpec, ...], dict]:
        spec = self.mapping(value, "cases", (), ("robots", "notional", "scene_template"))
        if "robots" not in spec and "notional" not in spec:
            raise self.fail("cases", "expected 'robots' (a list of {robot, scene} pairs) and/or "
                            "'notional' (grid, or {lambdas, mus} in mm)")
        if "scene_template" in spec and "notional" not in spec:
            raise self.fail("cases.scene_template", "only used with cases.notional")
        specs, raw = [], {}
        if "robots" in spec:
            entries = spec["robots"]
            if not isinstance(entries, list) or not entries:
                raise self.fail("cases.robots", f"expected a non-empty list of {{robot, scene}} "
                                f"pairs, got {entries!r}")
            specs += [self.robot_case(e, f"cases.robots[{i}]") for i, e in enumerate(entries)]
            raw["robots"] = [{"robot": s.robot, **({"scene": s.scene} if s.scene else
                                                    {"scene_template": s.template})}
                             for s in specs]
        if "notional" in spec:
            template = self.scene_ref(spec.get("scene_template", "fms_kr16"),
                                      "cases.scene_template")
            lambdas, mus = self.notional(spec["notional"])
            digest = self.digest(template)
            for lam in lambdas:
                for mu in mus:
                    robot = f"notional_l{lam}_m{mu}"
                    specs.append(CaseSpec(f"{robot}-scaled_{_label(template)}", robot,
                                          template=template, lambda_mm=lam, mu_mm=mu,
                                          scene_digest=digest))
            raw["notional"] = {"lambdas": list(lambdas), "mus": list(mus)}
            raw["scene_template"] = template
        return tuple(specs), raw

    def notional(self, value) -> tuple[tuple[int, ...], tuple[int, ...]]:
        key = "cases.notional"
        if value == "grid":
            return (tuple(round(v * 1000) for v in NOTIONAL_LAMBDAS),
                    tuple(round(v * 1000) for v in NOTIONAL_MUS))
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected 'grid' (the paper's 10 x 9 arms) or a mapping "
                            f"{{lambdas: [...], mus: [...]}} in mm, got {value!r}")
        spec = self.mapping(value, key, ("lambdas", "mus"))

        def length(v, k):
            if isinstance(v, bool) or not isinstance(v, int) or not 0 < v <= 5000:
                raise self.fail(k, f"expected a whole number of millimetres in (0, 5000] "
                                f"(e.g. 650), got {v!r}")
            return v

        return (self.items(spec["lambdas"], f"{key}.lambdas", length),
                self.items(spec["mus"], f"{key}.mus", length))

    def scene_ref(self, value, key) -> str:
        """A shipped scene name, or a file path made absolute."""
        name = self.string(value, key)
        if name in scene_names():
            return name
        path = Path(name).expanduser()
        path = path if path.is_absolute() else self.folder / path
        if not path.is_file():
            raise self.fail(key, f"no such scene file and no shipped scene {name!r}; shipped "
                            f"scenes are: {', '.join(scene_names())}")
        return str(path.resolve())

    def digest(self, scene: str) -> str:
        if scene in scene_names():
            return _file_digest(str(resources.files("calib_oed.scene.shipped").joinpath(f"{scene}.yaml")))
        return _file_digest(scene)

    def robot_case(self, value, key) -> CaseSpec:
        entry = self.mapping(value, key, ("robot",), ("scene", "scene_template"))
        robot = self.string(entry["robot"], f"{key}.robot")
        if ("scene" in entry) == ("scene_template" in entry):
            raise self.fail(key, "expected exactly one of 'scene' (the scene as is) or "
                            "'scene_template' (a KUKA-class scene scaled for the robot)")
        if "scene" in entry:
            scene = self.scene_ref(entry["scene"], f"{key}.scene")
            try:
                loaded = load_scene(scene)
            except CalibOedError as exc:
                raise self.fail(f"{key}.scene", str(exc)) from exc
            if loaded.robot.name != robot:
                raise self.fail(f"{key}.robot", f"scene {_label(scene)!r} has robot "
                                f"{loaded.robot.name!r}, not {robot!r}; use scene_template to "
                                f"scale a scene for another arm")
            return CaseSpec(f"{robot}-{_label(scene)}", robot, scene=scene,
                            scene_digest=self.digest(scene))
        template = self.scene_ref(entry["scene_template"], f"{key}.scene_template")
        try:
            kuka_dimensions(robot)
        except CalibOedError as exc:
            raise self.fail(f"{key}.robot", str(exc)) from exc
        match = NOTIONAL_PATTERN.match(robot)
        lam, mu = (int(match.group(1)), int(match.group(2))) if match else (None, None)
        return CaseSpec(f"{robot}-scaled_{_label(template)}", robot, template=template,
                        lambda_mm=lam, mu_mm=mu, scene_digest=self.digest(template))
