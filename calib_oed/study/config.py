r"""Study configurations as records: the cases, the plan each runs, and their hash.

A *study* is robots × scenes × criteria × collision settings × seeds. One
*case* (:class:`CaseSpec`) is one robot in one scene; the plan
(:class:`DesignPlan`) says what every case computes (:mod:`calib_oed.study.case`
runs it). A :class:`StudyConfig` holds both and expands into
:class:`StudyCase` units of work, each identified by the SHA-256 of what
determines its results (:attr:`StudyCase.config_hash`), so that a resumed
study reuses only results computed with the same settings. The records
validate themselves (``check``); the YAML files are read by
:mod:`calib_oed.study.loader`. Scaled scenes: :mod:`calib_oed.scene.scaling`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

from calib_oed.exceptions import StudyConfigError
from calib_oed.oed.criteria import CRITERIA
from calib_oed.oed.design import DESIGN_SQP
from calib_oed.oed.starts import STARTS
from calib_oed.scene.reader import load_scene
from calib_oed.scene.records import Scene
from calib_oed.scene.scaling import scaled_scene
from calib_oed.solver.sqp import SQPSettings

__all__ = ["CaseSpec", "CertificatePlan", "DesignPlan", "StudyCase", "StudyConfig"]

#: Version of the case computation; part of every case hash (bump when results change meaning).
CASE_FORMAT = "calib_oed study case v1"
DEFAULT_CRITERIA = ("params", "kpi")
DEFAULT_COLLISIONS = (True, False)
DEFAULT_HEURISTIC_SEEDS = tuple(range(10))


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
        enrich: The exchange start's pool enriched by the off-pool local maxima of the
            approximate design (``design(..., enrich=)``, the library's default);
            ``False``: the random pool alone, as the study tables of docs/study.md were computed.
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
    enrich: bool = True
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
        if not isinstance(self.enrich, bool):
            raise StudyConfigError(f"expected true or false, got {self.enrich!r}", key="enrich")
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
        if self.enrich:  # absent when off: the case hashes of studies run before it existed hold
            out["enrich"] = True
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
    """A case with the plan it runs: the unit of work of :func:`calib_oed.study.case.run_case`."""

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
        # enrich written either way: the plan's dict leaves it out when off (case hashes of
        # studies run before it existed), and the loader's default is on
        return {"version": 1, "name": self.name, "description": self.description,
                "cases": self.raw_cases, **self.plan.to_dict(), "enrich": self.plan.enrich}


def _label(scene: str) -> str:
    return Path(scene).stem if (os.sep in scene or scene.endswith((".yaml", ".yml"))) else scene
