r"""Tracker data of a realistic truth, the blocks :func:`~calib_oed.calibration.identification.identify` reads.

For every measurement model of the scene (one per reflector, position
measurements) and every commanded configuration :math:`q_i`:

.. math::
    \eta_i = \mathcal{T}\big(T_{W,T}^{-1}\,x_j(q_i, t_i)\big) + \varepsilon_i \;(+\;g_i)

with :math:`x_j` the true world position of reflector :math:`j`
(:meth:`RealisticTruth.compute_reflector_points`), :math:`T_{W,T}` the true
tracker pose, :math:`\mathcal{T}` the tracker's systematics, :math:`\varepsilon_i`
the scene's noise drawn at the true position (as
:func:`calib_oed.calibration.simulation.simulate_observations`) and
:math:`g_i` a gross error of ``settings.gross_size`` in a random direction on
``settings.gross_errors`` rows chosen at random. :math:`t_i \in [0, 1]` is the
time of row :math:`i` in the session (rows in measurement order).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from calib_oed.calibration.realistic import (
    Balancer,
    RealisticTruth,
    TrackerSystematics,
    Transmission,
    gravity_load,
)
from calib_oed.calibration.realistic_defaults import RealisticSettings
from calib_oed.calibration.simulation import add_noise
from calib_oed.exceptions import ParameterError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.measurement.position import TrackerPosition


@dataclass(frozen=True, eq=False)
class RealisticMeasurements:
    """Simulated tracker data of a realistic truth.

    Attributes:
        blocks: One :class:`ObservationBlock` per measurement model (reflector), noisy.
        exact: The noise-free readings (systematics included), (k, n, 3) [m, tracker frame].
        gross: ``(block, row)`` of every measurement with a gross error.
        time: Time of each row in the session, (n,) in [0, 1].
    """

    blocks: tuple[ObservationBlock, ...]
    exact: np.ndarray
    gross: tuple[tuple[int, int], ...]
    time: np.ndarray

    def measurement_set(self, robot, source: str = "<realistic simulation>") -> MeasurementSet:
        """The blocks as a :class:`MeasurementSet` (for measurement files)."""
        return blocks_to_measurement_set(robot, self.blocks, source)


def blocks_to_measurement_set(robot, blocks, source: str = "<simulation>") -> MeasurementSet:
    """Position (and pose) blocks of simulated data as one :class:`MeasurementSet`."""
    qs, pos, rot, refl = [], [], [], []
    for b in blocks:
        qs.append(b.q)
        pos.append(b.values[:, :3])
        refl.append(np.full(b.n, b.model.reflector))
        if b.model.dim == 6:
            rot.append(b.values[:, 3:])
    return MeasurementSet.from_arrays(robot, np.vstack(qs), np.vstack(pos), reflector=np.concatenate(refl),
                                      rotations=np.vstack(rot) if rot else None, source=source)


def measure(truth: RealisticTruth, models, q: np.ndarray, rng: np.random.Generator | int,
            time: np.ndarray | None = None) -> RealisticMeasurements:
    """Noisy tracker readings of ``truth`` by every model of ``models`` at ``q`` (n, nq).

    Args:
        truth: The realistic robot and tracker.
        models: The scene's measurement models (``setup.problem.models``); position models only.
        q: Commanded configurations in measurement order, (n, nq) [rad].
        rng: Noise and gross errors.
        time: Time of each row in the session (n,) in [0, 1]; None: evenly spread in row order.

    Raises:
        ParameterError: a model that is not a position measurement (``measurement: pose``).
    """
    rng = np.random.default_rng(rng)
    q = truth.space.robot.check_configurations(q)
    n = q.shape[0]
    t = np.linspace(0.0, 1.0, n) if time is None else np.asarray(time, dtype=float).reshape(n)
    for mdl in models:
        if not isinstance(mdl, TrackerPosition):
            raise ParameterError(f"the realistic simulator measures reflector positions only "
                                 f"(measurement: position), not {type(mdl).__name__}")
    world = truth.compute_reflector_points(q, t)
    exact = np.stack([truth.compute_tracker_readings(world[:, mdl.reflector]) for mdl in models])
    noisy = [add_noise(mdl, exact[j], rng) for j, mdl in enumerate(models)]
    settings = truth.settings
    gross: list[tuple[int, int]] = []
    n_gross = int(settings.gross_errors)
    if n_gross:
        if n_gross > n * len(models):
            raise ParameterError(f"realistic.gross_errors: {n_gross} is more than the "
                                 f"{n * len(models)} measurements")
        picks = rng.choice(n * len(models), size=n_gross, replace=False)
        for k in np.sort(picks):
            j, i = divmod(int(k), n)
            u = rng.normal(size=3)
            noisy[j][i] += settings.gross_size * u / np.linalg.norm(u)
            gross.append((j, i))
    blocks = tuple(ObservationBlock(mdl, q, noisy[j]) for j, mdl in enumerate(models))
    exact.setflags(write=False)
    t.setflags(write=False)
    return RealisticMeasurements(blocks, exact, tuple(gross), t)


def truth_record(truth: RealisticTruth, scene_name: str, truth_seed: int) -> dict:
    """Every component of ``truth`` and its values (SI; Python floats and lists), for a YAML file."""
    space, tr, b = truth.space, truth.transmission, truth.balancer
    return {
        "scene": scene_name,
        "truth_seed": int(truth_seed),
        "kind": "realistic",
        "units": "SI (m, rad, N m/rad, rad/(N m), kg; scale [1])",
        "settings": truth.settings.describe(),
        "parameters": dict(zip(space.names, truth.p.tolist(), strict=True)),
        "compliance": {"stiffness": truth.stiffness.tolist(), "applied_compliance": truth.compliance.tolist(),
                       "payload_mass": float(truth.payload_mass), "payload_com": truth.payload_com.tolist()},
        "transmission": {k: np.asarray(getattr(tr, k)).tolist() for k in (
            "gear_ratios", "joint_amplitude", "joint_phase", "motor_amplitude", "motor_phase")},
        "balancer": None if b is None else {"joint": b.joint + 1, "torque": float(b.torque),
                                            "theta0": float(b.theta0), "rho": float(b.rho),
                                            "kappa": float(b.kappa)},
        "thermal_expansion": float(truth.thermal_expansion),
        "tracker": {k: float(v) for k, v in dataclasses.asdict(truth.tracker).items()},
        "gain_errors": None if truth.gain_errors is None else truth.gain_errors.tolist(),
    }


def write_realistic_truth(path: str | os.PathLike, truth: RealisticTruth, scene_name: str, truth_seed: int,
                          measurements: RealisticMeasurements | None = None) -> Path:
    """The truth of a realistic simulation as YAML (atomic); with the gross-error rows if given.

    Its ``parameters`` block is what :func:`calib_oed.calibration.workflow.read_truth` reads
    (the geometric part of the truth).
    """
    rec = truth_record(truth, scene_name, truth_seed)
    if measurements is not None:
        rec["gross_errors"] = [{"reflector": j, "row": i} for j, i in measurements.gross]
    return atomic_write_text(path, "# calib_oed realistic simulated truth\n" + yaml.safe_dump(rec, sort_keys=False))


def _gain_errors(value, nv: int, source) -> np.ndarray | None:
    """``gain_errors`` of a truth record: None (``null``, as written for a truth without
    them, or the key left out) is no gain error; else ``nv`` finite numbers [rad/rad]."""
    if value is None:
        return None
    gains = np.array(value, dtype=float)
    if gains.shape != (nv,) or not np.all(np.isfinite(gains)):
        raise ParameterError(f"{source}: gain_errors {value!r}: give {nv} finite numbers [rad/rad], "
                             "or null for none")
    return gains


def read_realistic_truth(data: dict, setup, source: str | os.PathLike = "<truth>") -> RealisticTruth:
    """The :class:`RealisticTruth` of a :func:`write_realistic_truth` record (its parsed YAML).

    Raises:
        ParameterError: a missing or malformed entry, named with the file.
    """
    space = setup.problem.space
    try:
        p = np.zeros(space.size)
        for name, value in data["parameters"].items():
            p[space.index(name)] = float(value)
        comp, tr, tk, bal = data["compliance"], data["transmission"], data["tracker"], data["balancer"]
        mass, com = float(comp["payload_mass"]), np.array(comp["payload_com"], dtype=float)
        arrays = [np.array(tr[k], dtype=float) for k in ("gear_ratios", "joint_amplitude", "joint_phase",
                                                          "motor_amplitude", "motor_phase")]
        truth = RealisticTruth(
            space, RealisticSettings.from_record(data["settings"]), p,
            np.array(comp["stiffness"], dtype=float), np.array(comp["applied_compliance"], dtype=float),
            mass, com, Transmission(*arrays),
            None if bal is None else Balancer(int(bal["joint"]) - 1, float(bal["torque"]), float(bal["theta0"]),
                                              float(bal["rho"]), float(bal["kappa"])),
            float(data["thermal_expansion"]), TrackerSystematics(**{k: float(v) for k, v in tk.items()}),
            gravity_load(setup.scene, space.robot, mass, com),
            _gain_errors(data.get("gain_errors"), space.robot.model.nv, source))
    except ParameterError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ParameterError(f"{source}: not a realistic truth file of scene {setup.scene.name} "
                             f"({type(exc).__name__}: {exc})") from exc
    nv = space.robot.model.nv
    if truth.stiffness.shape != (nv,) or truth.transmission.joint_amplitude.shape != (nv, 2):
        raise ParameterError(f"{source}: the truth has joint arrays for another robot (expected {nv} joints)")
    return truth
