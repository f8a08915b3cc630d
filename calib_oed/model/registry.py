"""Names of the robots :func:`calib_oed.load_robot` knows.

Three sources, looked up in this order:

1. our own URDFs in the top-level ``urdf/`` folder (shipped as the package
   ``calib_oed.urdf``): ``kr16``, ``kr300``, ``kr500``;
2. the paper's notional manipulators, generated on demand:
   ``notional_l{lambda_mm}_m{mu_mm}``, e.g. ``notional_l650_m600``;
3. serial arms of the ``example-robot-data`` wheel, which ships URDFs under
   ``site-packages/cmeel.prefix/share/example-robot-data/robots`` and no Python
   loader. Meshes are resolved with ``package_dirs = [.../cmeel.prefix/share]``.
"""

from __future__ import annotations

import importlib.metadata
import re
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path


@dataclass(frozen=True)
class ExampleRobot:
    """An arm of the example-robot-data wheel.

    Attributes:
        name: Name to load it by.
        urdf: URDF path relative to the wheel's ``robots`` folder.
        tool_frame: Default tool frame.
        locked_joints: Joints held fixed (name to value [rad or m]) so that
            the model is a serial chain up to the tool frame (gripper fingers).
    """

    name: str
    urdf: str
    tool_frame: str
    locked_joints: dict[str, float] = field(default_factory=dict)


EXAMPLE_ROBOTS: dict[str, ExampleRobot] = {
    r.name: r
    for r in (
        ExampleRobot("ur3", "ur_description/urdf/ur3_robot.urdf", "tool0"),
        ExampleRobot("ur5", "ur_description/urdf/ur5_robot.urdf", "tool0"),
        ExampleRobot("ur10", "ur_description/urdf/ur10_robot.urdf", "tool0"),
        ExampleRobot(
            "panda",
            "panda_description/urdf/panda.urdf",
            "panda_hand_tcp",
            {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0},
        ),
        ExampleRobot("z1", "z1_description/urdf/z1.urdf", "gripperStator", {"jointGripper": 0.0}),
        ExampleRobot("xarm7", "xarm_description/urdf/xarm7.urdf", "link7"),
    )
}

# Our own URDFs: tool frame of each.
OWN_ROBOTS: dict[str, str] = {"kr16": "tool0", "kr300": "tool0", "kr500": "tool0"}

NOTIONAL_PATTERN = re.compile(r"^notional_l(\d+)_m(\d+)$")


@cache
def example_robot_data_share() -> Path | None:
    """The ``share`` folder of the installed example-robot-data wheel, or None."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        return None
    share = Path(str(dist.locate_file("cmeel.prefix/share")))
    return share if (share / "example-robot-data" / "robots").is_dir() else None


def own_urdf_path(name: str) -> Path:
    """Path of one of our shipped URDFs (``urdf/<name>.urdf``)."""
    return Path(str(resources.files("calib_oed.urdf").joinpath(f"{name}.urdf")))


def robot_names() -> list[str]:
    """All robot names that load without a path (notional arms as a pattern)."""
    names = list(OWN_ROBOTS)
    if example_robot_data_share() is not None:
        names += list(EXAMPLE_ROBOTS)
    names.append("notional_l<lambda_mm>_m<mu_mm>")
    return names
