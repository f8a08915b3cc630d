r"""Adopting a registration into the scene: ``identify --adopt-registration FILE``.

The tracker pose :math:`T_{W,T}` and the reflector offsets :math:`c_j` are fitted
together to the measured positions with the robot nominal (the alternating fit of
:func:`calibration.sanity.fit_tracker_and_offsets`). The scene is written again with
``tracker.position`` and ``tracker.rpy`` replaced by the fitted pose, and each
reflector's ``offset`` replaced when the fit moves it by more than
:data:`ADOPT_OFFSET_MIN` (a stem or an adapter the scene got wrong; smaller differences
are what the identification estimates as the reflector parameters). Values are written
in the scene's own units; the rest of the scene is kept (its comments are not: YAML
loses them), with an ``include:`` resolved.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from calib_oed.calibration.registration import pose_difference, rigid_registration
from calib_oed.calibration.sanity import fit_tracker_and_offsets
from calib_oed.exceptions import SceneError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.model.parameters import ParameterSpace
from calib_oed.scene.include import resolve_includes
from calib_oed.scene.records import Scene
from calib_oed.scene.yaml_file import load_yaml_file
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

__all__ = ["ADOPT_OFFSET_MIN", "AdoptedRegistration", "adopt_registration"]

#: Smallest change of a reflector offset that is adopted [m].
ADOPT_OFFSET_MIN = 5e-4


@dataclass(frozen=True)
class AdoptedRegistration:
    """What was adopted: the fitted tracker pose, the offsets, the file written.

    Attributes:
        path: The scene file written.
        placement: Fitted :math:`T_{W,T}`.
        shift_mm, turn_deg: How far it is from the scene's tracker pose.
        offsets: Fitted reflector offsets (k, 3) [m, tool frame].
        adopted: Names of the reflectors whose offsets were replaced.
        rms_before_mm, rms_mm: Registration RMS with the scene's offsets and with the fitted ones.
    """

    path: Path
    placement: pin.SE3
    shift_mm: float
    turn_deg: float
    offsets: np.ndarray
    adopted: tuple[str, ...]
    rms_before_mm: float
    rms_mm: float

    def summary(self) -> str:
        moved = (f"; reflector offsets adopted: {', '.join(self.adopted)}" if self.adopted
                 else "; the reflector offsets agree with the scene's (kept)")
        return (f"adopted the registration into {self.path}: tracker pose moved {self.shift_mm:.2f} mm, "
                f"{self.turn_deg:.3f} deg{moved}; registration RMS {self.rms_before_mm:.4f} mm -> "
                f"{self.rms_mm:.4f} mm")


def adopt_registration(scene: Scene, space: ParameterSpace, mset: MeasurementSet,
                       path: str | os.PathLike) -> AdoptedRegistration:
    """Fit the tracker pose and reflector offsets to ``mset`` and write the updated scene to ``path``.

    Raises:
        SceneError: the scene has no file to start from.
        ExportError: ``path`` cannot be written.
    """
    if scene.source is None:
        raise SceneError("--adopt-registration needs a scene read from a file (a shipped name or a path)")
    state = evaluate_setup(space, None, mset.q, regressor=False, jacobian=False)
    kin_rot, kin_pos = state.kin.rotation, state.kin.translation
    k = len(space.reflector_offsets0)
    fixed = kin_pos + np.einsum("nij,nj->ni", kin_rot, space.reflector_offsets0[mset.reflector])
    before = rigid_registration(fixed, mset.positions)
    _, offsets = fit_tracker_and_offsets(kin_rot, kin_pos, mset.positions, mset.reflector, k)
    names = [r.name for r in scene.reflectors]
    moved = [j for j in mset.reflectors
             if np.linalg.norm(offsets[j] - space.reflector_offsets0[j]) > ADOPT_OFFSET_MIN]
    use = space.reflector_offsets0.copy()
    use[moved] = offsets[moved]
    reg = rigid_registration(kin_pos + np.einsum("nij,nj->ni", kin_rot, use[mset.reflector]), mset.positions)
    data = resolve_includes(load_yaml_file(scene.source, "scene file"), Path(scene.source))
    length = LENGTH_UNITS[data["units"]["length"]]
    angle = ANGLE_UNITS[data["units"]["angle"]]
    placement = reg.placement
    data["tracker"]["position"] = [round(float(v) / length, 9) for v in placement.translation]
    data["tracker"]["rpy"] = [round(float(v) / angle, 9) for v in pin.rpy.matrixToRpy(placement.rotation)]
    for j in moved:
        data["reflectors"][j]["offset"] = [round(float(v) / length, 9) for v in use[j]]
    shift, turn = pose_difference(scene.tracker.placement(), placement)
    header = (f"# {scene.name} with the tracker pose{' and reflector offsets' if moved else ''} "
              f"fitted to {mset.source} (calib-oed identify --adopt-registration);\n"
              f"# registration RMS {reg.rms_mm:.4f} mm. Written from {scene.source}; its comments "
              "are not kept.\n")
    out = atomic_write_text(path, header + yaml.safe_dump(data, sort_keys=False, allow_unicode=True,
                                                          default_flow_style=None, width=100))
    return AdoptedRegistration(out, placement, shift, turn, use, tuple(names[j] for j in moved),
                               before.rms_mm, reg.rms_mm)
