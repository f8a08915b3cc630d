r"""Reading study configurations: shipped ones by name, YAML files, key by key.

A *study* is robots × scenes × criteria × collision settings × seeds. One
*case* is one robot in one scene; in every case :mod:`calib_oed.study.case` runs
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
    enrich: true                             # exchange: pool + off-pool maxima (false: pool only)
    seed: 0                                  # seed of the start design
    sqp: {max_iterations: 80, time_limit: null} # per SQP run; a time limit [s] makes results load-dependent
    certificate: {pool: 3000, seed: 0, local_starts: 32}   # optional: KPI lower bound per case

Errors raise :class:`~calib_oed.exceptions.StudyConfigError` naming the
dotted key and the valid choices. The records built are those of
:mod:`calib_oed.study.config`. Scaled scenes: :mod:`calib_oed.scene.scaling`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from calib_oed.exceptions import CalibOedError, StudyConfigError
from calib_oed.model.kuka import NOTIONAL_LAMBDAS, NOTIONAL_MUS
from calib_oed.model.registry import NOTIONAL_PATTERN
from calib_oed.oed.criteria import CRITERIA
from calib_oed.oed.design import DESIGN_SQP
from calib_oed.oed.starts import STARTS
from calib_oed.scene.fields import FieldReader
from calib_oed.scene.reader import SHIPPED, load_scene, scene_names
from calib_oed.scene.scaling import kuka_dimensions
from calib_oed.scene.yaml_file import load_yaml_file, shipped_file, shipped_names
from calib_oed.study.config import (
    DEFAULT_COLLISIONS,
    DEFAULT_CRITERIA,
    DEFAULT_HEURISTIC_SEEDS,
    CaseSpec,
    CertificatePlan,
    DesignPlan,
    StudyConfig,
    _label,
)

__all__ = ["load_study_config", "study_config_from_dict", "study_names"]

SUPPORTED_VERSIONS = (1,)
_TOP_REQUIRED = ("version", "name", "cases")
_TOP_OPTIONAL = ("description", "n", "heuristic_seeds", "criteria", "collisions", "start", "enrich",
                 "seed", "sqp", "certificate")


def study_names() -> list[str]:
    """Names of the shipped study configurations (``calib_oed/study/shipped/<name>.yaml``)."""
    return shipped_names("calib_oed.study.shipped")


def load_study_config(name_or_path: str | os.PathLike) -> StudyConfig:
    """A shipped study configuration by name, or a configuration file by path.

    Raises:
        StudyConfigError: unknown name (lists the shipped studies), unreadable
            file, YAML error or invalid content.
    """
    text = os.fspath(name_or_path)
    path = shipped_file("calib_oed.study.shipped", text)
    if path is None:
        path = Path(text)
        if not path.is_file():
            raise StudyConfigError(f"no such file and no shipped study of that name; shipped "
                                   f"studies are: {', '.join(study_names())}", source=text)
    try:
        data = load_yaml_file(path, "study configuration")
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


class _Reader(FieldReader):
    """Key-by-key validation; errors name the dotted key and the valid choices."""

    def __init__(self, source: str | None):
        super().__init__(source)
        self.folder = Path(source).parent if source else Path.cwd()

    def fail(self, key: str | None, message: str) -> StudyConfigError:
        return StudyConfigError(message, key=key, source=self.source)

    def boolean(self, value, key) -> bool:
        if not isinstance(value, bool):
            raise self.fail(key, f"expected true or false, got {value!r}")
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
            enrich=self.boolean(top.get("enrich", True), "enrich"),
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
        return _file_digest(str(shipped_file(SHIPPED, scene) or scene))

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
