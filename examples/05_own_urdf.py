"""05 — Bring your own robot and cell: a scene from a URDF file, built in Python.

A template to copy. It describes a calibration set-up as a Python dict with
exactly the keys of a scene YAML file (schema: docs/scenes.md), for a robot
given as a URDF *file path*: your robot, your laser tracker placement, your
reflector on the tool, the KPI (a tool point at your working
configurations), your cell's obstacles and your safety margins. Then it does
what you would do first with a new cell:

1. identifiability: how many parameters the tracker data determine, and
   whether the KPI is estimable (docs/conventions.md);
2. a short KPI-optimal design of 30 poses, from a heuristic start;
3. feasibility: the design against the capsule model (with margins) and,
   independently, against the URDF's own collision geometry;
4. the same scene saved as YAML, for the command line.

The URDF here is a copy of our KR 16-class URDF, standing in for yours: set
URDF_PATH to your file. The copy and the scene YAML are written to a new folder
in the temporary directory (kept, and printed), or beside the `.yaml` path you
give: ``python examples/05_own_urdf.py my_cell/my_cell.yaml``. Mesh paths in a URDF
(``package://pkg/...`` or relative) are searched in the URDF's folder, so keep
the URDF next to its ``pkg`` folder; or give the link capsules yourself
(``feasibility.robot_capsules``, docs/feasibility.md §2).

Checks: the identifiable count is the classical rule's (one reflector off the
last joint axis: 4R + 3 = 27); the YAML file loads to the same scene; the
design improves the KPI over its start and every pose is feasible, on the
capsules and on the URDF collision geometry.

Run: .venv/bin/python examples/05_own_urdf.py   (about 9 s of CPU)
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from calib_oed import load_scene, scene_from_dict, setup
from calib_oed.calibration.report import classical_count
from calib_oed.feasibility.margins import format_margins
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.model.registry import own_urdf_path
from calib_oed.oed.design import DESIGN_SQP, FEASIBILITY_TOL, design, heuristic_designs
from calib_oed.oed.result import format_design_table

# Where the URDF copy and the scene YAML go: a `.yaml` path given on the command line, else a
# new folder kept in the temporary directory (printed at the end, so the command it suggests works).
given = [a for a in sys.argv[1:] if a.endswith((".yaml", ".yml"))]  # (the test runner's arguments are not)
tmp = Path(given[0]).resolve().parent if given else Path(tempfile.mkdtemp(prefix="calib_oed_example05_"))
tmp.mkdir(parents=True, exist_ok=True)
URDF_PATH = tmp / "my_robot.urdf"                # <- your URDF file
shutil.copy(own_urdf_path("kr16"), URDF_PATH)    # (stand-in: our KR 16-class URDF)

# A welding cell: the robot on the floor, a fixture table in front of it (+x), a wall
# behind it, the tracker on a stand to the robot's left (+y). World frame = robot base
# frame, z up; every length below in mm, every angle in deg (the `units` key).
cell = {
    "version": 1,                                # scene schema version
    "name": "my_welding_cell",
    "description": "KR 16-class arm, welding fixture, tracker on the left",
    "units": {"length": "mm", "angle": "deg"},   # units of every number below; SI also works
    "robot": {
        "urdf": str(URDF_PATH),                  # a URDF file (relative: to the scene file's folder)
        "tool_frame": "tool0",                   # frame the reflector and the KPI point are given in
        "joint_limits": {"joint_a1": [-120, 120]},   # [deg] overrides, e.g. cable dress; rest: URDF's
        # "lock_joints": {"gripper_joint": 0},   # [deg] joints held fixed (grippers, tracks)
    },
    "tracker": {
        "position": [700, 2300, 1400],           # [mm] tracker origin in the world (head 1.4 m high)
        "rpy": [0, 10, -90],                     # [deg] roll, pitch, yaw: x axis to -y (the robot), 10 deg down
        "sigma": 0.01,                           # [mm] noise std per tracker axis (or [sx, sy, sz])
        # "sigma_angle": 0.01,                   # [deg] only for `measurement: pose` (6-D probe)
    },
    "reflectors": [                              # SMRs on the tool, centres in the tool frame
        {"name": "smr0", "offset": [30, 0, 60]},  # [mm] off the A6 axis: 2 more parameters identifiable
    ],
    "measurement": "position",                   # `position` (3-D, per reflector) or `pose` (6-D probe)
    "kpi": {
        "point": [0, 0, 250],                    # [mm] torch tip in the tool frame (default: the TCP, 0)
        "frame": "world",                        # `world` or `tracker` (with `reflector`: estimable)
        "working_configurations": [              # [deg] where the robot works: the KPI's poses
            {"name": "seam_left", "q": [-15, -60, 100, 0, 50, 0]},
            {"name": "seam_right", "q": [15, -60, 100, 0, 50, 0]},
        ],
    },
    "generic_design": {"n": 200, "seed": 0},     # random poses the gauge rule uses (the defaults)
    "cell": {                                    # world-fixed obstacles
        "capsules": [                            # points within `radius` [mm] of segment a-b [mm]
            {"name": "fixture", "a": [1150, -700, 150], "b": [1150, 700, 150], "radius": 150},
            {"name": "tracker_stand", "a": [700, 2300, 0], "b": [700, 2300, 1100], "radius": 100},
        ],
        "halfspaces": [                          # free sides: z >= 0, x >= -600 mm
            {"name": "floor", "z_min": 0},
            {"name": "wall", "x_min": -600},
        ],
    },
    "feasibility": {                             # every key optional; defaults in docs/scenes.md
        "incidence_limit": 30,                   # [deg] reflector axis (tool z) to the tracker direction
        "beam_radius": 5,                        # [mm] laser beam capsule
        "reflector_radius": 19.05,               # [mm] stem + 1.5" SMR capsule
        "margins": {"clearance": 15, "incidence": 2, "joint": 1},   # [mm], [deg], [deg] kept free
        # "excluded_pairs": [["link_1", "link_3"]],   # link pairs never checked
    },
}
scene = scene_from_dict(cell)                    # validates every key; errors name the key
s = setup(scene)
problem = s.problem

# --- 1. identifiability and estimability -----------------------------------------------
report = problem.identifiability
count, rule = classical_count(problem)
print(f"{scene.name}: robot {scene.robot.name} from {URDF_PATH.name}, {scene.robot.nq} joints; "
      f"{report.rank} of {len(report.names)} parameters identifiable (classical {rule} = {count}), "
      f"condition number {report.condition_number:.1f}")
if report.rank != count:                        # a reflector on the last axis would give count - 2
    raise SystemExit(f"expected {count} identifiable parameters, got {report.rank}")
for est in problem.kpi_estimability():
    print(f"  KPI {est.label}: " + ("estimable" if est.estimable else
                                     f"relative to the gauge ({', '.join(est.gauge[:3])}, ...)"))

# --- 2. a short KPI-optimal design -------------------------------------------------------
heuristic = heuristic_designs(s, 30, seeds=[0])[0]
optimal = design(s, 30, "kpi", start=heuristic.q, certificate=False,   # no optimality bound: a short run
                 settings=dataclasses.replace(DESIGN_SQP, max_iterations=60))
print(format_design_table({"heuristic": heuristic, "KPI-optimal": optimal}))
if not optimal.kpi_variance < heuristic.kpi_variance:
    raise SystemExit("the optimised design is not better than its start")

# --- 3. feasibility: capsule model with margins, then the URDF geometry itself -----------
# Rows g(q) >= 0 per pose [m, cos, rad]. An optimal design sits on its active constraints,
# so count a pose feasible up to the designer's tolerance (1 um against the 15 mm margin).
values = s.feasibility.compute(optimal.q, jacobian=False).values      # (30, rows)
worst = values.min(axis=1)
print(f"capsule model: {int((worst >= -FEASIBILITY_TOL).sum())} of {optimal.n} poses feasible, "
      f"largest violation {max(0.0, -worst.min()):.1e} (tolerance {FEASIBILITY_TOL:g})")
print(format_margins(list(optimal.margins)))     # the tightest constraint of each kind
mesh = check_design_meshes(
    scene.robot, optimal.q, scene.cell,
    tracker_position=scene.tracker.placement().translation,
    reflector_offsets=np.array([r.offset for r in scene.reflectors]),
    beam_radius=scene.feasibility.beam_radius,
    excluded_pairs=scene.feasibility.excluded_pairs,
)
print(mesh.summary(max_lines=3))
if not (optimal.feasible and worst.min() >= -FEASIBILITY_TOL):
    raise SystemExit("the design violates a constraint of the capsule model")
if not mesh.all_feasible:
    raise SystemExit("a pose touches the URDF collision geometry or blocks the beam")

# --- 4. the same scene as a YAML file, for `calib-oed ... my_cell.yaml` -------------------
path = Path(given[0]).resolve() if given else tmp / "my_cell.yaml"
path.write_text(yaml.safe_dump(cell, sort_keys=False))
again = setup(load_scene(path))
if again.problem.identifiability.fixed_names != report.fixed_names or not np.allclose(
        again.scene.tracker.placement().homogeneous, scene.tracker.placement().homogeneous):
    raise SystemExit("the YAML file does not load to the same scene")
print(f"saved the scene as {path} (its URDF beside it); use it as `calib-oed identifiability {path}`, "
      f"`calib-oed design {path} -n 60 -o opt`")
print("OK")
