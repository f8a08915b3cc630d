r"""KUKA-class 6R arm descriptions: published dimensions and our own simplified URDFs.

The URDFs follow the layout of the ROS-Industrial ``kuka_experimental`` support packages
(see ``urdf/README.md``). Every link frame is parallel to the base frame at the zero pose
:math:`q = 0`, where the arm is stretched horizontally along :math:`+x`:

===================  =============  =======================  ================================
joint                parent         origin in parent [m]     axis
===================  =============  =======================  ================================
``joint_a1``         ``base_link``  :math:`(0, 0, d_1)`      (0, 0, -1)
``joint_a2``         ``link_1``     :math:`(a_1, 0, 0)`      (0, 1, 0)
``joint_a3``         ``link_2``     :math:`(a_2, 0, 0)`      (0, 1, 0)
``joint_a4``         ``link_3``     :math:`(d_4, 0, a_3)`    (-1, 0, 0)
``joint_a5``         ``link_4``     :math:`(0, 0, 0)`        (0, 1, 0)
``joint_a6``         ``link_5``     :math:`(0, 0, 0)`        (-1, 0, 0)
``joint_a6-flange``  ``link_6``     :math:`(d_6, 0, 0)`      fixed
``flange-tool0``     ``flange``     :math:`(0, 0, 0)`        fixed, rpy :math:`(0, \pi/2, 0)`
===================  =============  =======================  ================================

Axes A4, A5 and A6 intersect in the wrist centre (the origin of ``link_4`` to ``link_6``).
KUKA's elbow offset :math:`a_3` is negative, so the wrist centre sits :math:`|a_3|` below
the A3 axis at the zero pose, as in the ROS-Industrial KR 16-2 package. ``flange`` has the
axes of ``link_6`` (:math:`x` out of the flange); ``tool0`` is KUKA's $FLANGE frame, with
:math:`z` out of the flange along the A6 axis. Hence, with :math:`q = 0`,

.. math::

    p_{\mathrm{tool0}} = (a_1 + a_2 + d_4 + d_6,\; 0,\; d_1 + a_3), \quad
    z_{\mathrm{tool0}} = (1, 0, 0),

and in KUKA's home pose (A2 = -90°, A3 = +90°, others 0) the upper arm is vertical and

.. math::

    p_{\mathrm{tool0}} = (a_1 + d_4 + d_6,\; 0,\; d_1 + a_2 + a_3), \quad
    z_{\mathrm{tool0}} = (1, 0, 0).

A positive A1 angle turns the arm clockwise seen from above (towards :math:`-y`).
Geometry (cylinders and a wrist sphere), masses, efforts and velocities are rough guesses
scaled with the robot's size; only the kinematics and joint ranges are published facts.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

from calib_oed.exceptions import JointLimitError, ParameterError

__all__ = [
    "KR16", "KR300", "KR500", "KUKA_ROBOTS", "NOTIONAL_LAMBDAS", "NOTIONAL_MUS",
    "KukaDimensions", "kuka_urdf", "notional_dimensions",
    "notional_grid", "write_kuka_urdf",
]  # fmt: skip


@dataclass(frozen=True)
class KukaDimensions:
    """Kinematic dimensions and joint ranges of a KUKA-class 6R arm.

    Attributes:
        name: Robot name, also the URDF ``<robot name>``.
        d1: Height of axis A2 above the base [m].
        a1: Horizontal offset from axis A1 to axis A2 [m].
        a2: Upper-arm length, axis A2 to axis A3 [m].
        a3: Elbow offset, from axis A3 to the forearm axis A4, KUKA's sign
            (negative: the forearm lies below A3 at the zero pose) [m].
        d4: Forearm length, axis A3 to the wrist centre along A4 [m].
        d6: Wrist centre to the flange [m].
        lower: Lower joint limits of A1..A6 [rad].
        upper: Upper joint limits of A1..A6 [rad].
        source: Where the numbers come from.
    """

    name: str
    d1: float
    a1: float
    a2: float
    a3: float
    d4: float
    d6: float
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    source: str

    def __post_init__(self) -> None:
        for key in ("d1", "a1", "a2", "a3", "d4", "d6"):
            value = float(getattr(self, key))
            if not math.isfinite(value):
                raise ParameterError(f"{self.name}: {key} must be finite, got {value} [m]")
            object.__setattr__(self, key, value)
        for key in ("a2", "d4"):
            if getattr(self, key) <= 0.0:
                raise ParameterError(f"{self.name}: {key} must be positive [m]")
        for key in ("lower", "upper"):
            limits = tuple(float(v) for v in getattr(self, key))
            if len(limits) != 6 or not all(math.isfinite(v) for v in limits):
                raise JointLimitError(f"{self.name}: {key} needs 6 finite values [rad]")
            object.__setattr__(self, key, limits)
        bad = [f"A{i + 1}" for i in range(6) if not self.lower[i] < self.upper[i]]
        if bad:
            raise JointLimitError(f"{self.name}: lower >= upper for axes {', '.join(bad)}")

    @property
    def reach(self) -> float:
        """KUKA's nominal reach, axis A1 to the stretched wrist centre [m]."""
        return self.a1 + self.a2 + math.hypot(self.d4, self.a3)


def _published(
    name: str, mm: tuple[float, ...], deg_ranges: tuple[tuple[float, float], ...], source: str
) -> KukaDimensions:
    """Build dimensions from the table's millimetres and degrees."""
    d1, a1, a2, a3, d4, d6 = (v / 1000.0 for v in mm)
    lower = tuple(math.radians(lo) for lo, _ in deg_ranges)
    upper = tuple(math.radians(hi) for _, hi in deg_ranges)
    return KukaDimensions(name, d1, a1, a2, a3, d4, d6, lower, upper, source)


_ROSI = "ROS-Industrial kuka_experimental support packages (KR 16-2)"
_CATALOGUE = "robotkinematicscatalogue checked against RoboDK"
KR16 = _published(
    "kr16", (675, 260, 680, -35, 670, 158),
    ((-185, 185), (-155, 35), (-130, 154), (-350, 350), (-130, 130), (-350, 350)), _ROSI,
)  # fmt: skip
KR300 = _published(
    "kr300", (675, 350, 1150, -41, 1000, 240),
    ((-185, 185), (-140, -5), (-120, 155), (-350, 350), (-122.5, 122.5), (-350, 350)),
    f"{_CATALOGUE} (KR 300 R2500 ultra)",
)  # fmt: skip
KR500 = _published(
    "kr500", (1045, 500, 1300, -55, 1025, 290),
    ((-185, 185), (-130, 20), (-100, 144), (-350, 350), (-120, 120), (-350, 350)),
    f"{_CATALOGUE} (KR 500 R2830 / KR 500-3)",
)  # fmt: skip
KUKA_ROBOTS: dict[str, KukaDimensions] = {"kr16": KR16, "kr300": KR300, "kr500": KR500}

# The paper's text: λ ∈ {650, ..., 1100} mm and μ ∈ {600, ..., 1000} mm, 10 × 9 = 90 arms.
# (The caption of its Table 2 says 650..1050 and 600..1050, also 90; we follow the text.)
NOTIONAL_LAMBDAS = (0.65, 0.70, 0.75, 0.80, 0.85, 0.90, 0.95, 1.00, 1.05, 1.10)
NOTIONAL_MUS = (0.60, 0.65, 0.70, 0.75, 0.80, 0.85, 0.90, 0.95, 1.00)


def _mm(x: float) -> str:
    return f"{round(x * 1000.0, 3):g}"


def notional_dimensions(lam: float, mu: float) -> KukaDimensions:
    r"""The paper's notional manipulator: the KR 16-2 with a2 = ``lam`` and d4 = ``mu``.

    Args:
        lam: Length of segment two, the upper arm :math:`\lambda` [m].
        mu: Length of segment four, the forearm :math:`\mu` [m].

    Raises:
        ParameterError: ``lam`` or ``mu`` is not a finite length in (0, 5] m.
    """
    for symbol, what, value in (("lam", "upper-arm length λ", lam), ("mu", "forearm length μ", mu)):
        x = float(value)
        if not (math.isfinite(x) and x > 0.0):
            raise ParameterError(
                f"{symbol} ({what}) must be a positive finite length in metres, got {value!r}"
            )
        if x > 5.0:
            raise ParameterError(
                f"{symbol} ({what}) = {value!r} m is implausible; lengths are "
                f"in metres (0.65 for 650 mm)"
            )
    return replace(
        KR16,
        name=f"notional_l{_mm(lam)}_m{_mm(mu)}",
        a2=float(lam),
        d4=float(mu),
        source=f"notional manipulator of the KPI-OED paper: KR 16-2 ({KR16.source}) "
        f"with a2 = {_mm(lam)} mm, d4 = {_mm(mu)} mm",
    )


def notional_grid() -> list[KukaDimensions]:
    """The 90 notional manipulators, λ-major (all μ for the first λ, then the next λ)."""
    return [notional_dimensions(lam, mu) for lam in NOTIONAL_LAMBDAS for mu in NOTIONAL_MUS]


# ---------------------------------------------------------------- URDF generation

_DENSITY = 1600.0  # effective density of the simplified solids [kg/m^3]; KR 16 ~ 240 kg
_KR16_VELOCITY = (156.0, 156.0, 156.0, 330.0, 330.0, 615.0)  # [deg/s]
_HALF_PI = math.pi / 2.0
_AXIS_RPY = {"x": (0.0, _HALF_PI, 0.0), "y": (_HALF_PI, 0.0, 0.0), "z": (0.0, 0.0, 0.0)}
_JOINT_AXES = ((0, 0, -1), (0, 1, 0), (0, 1, 0), (-1, 0, 0), (0, 1, 0), (-1, 0, 0))


class _Shape(NamedTuple):
    """A cylinder along ``axis`` or (``axis`` None) a sphere, in link coordinates [m]."""

    centre: tuple[float, float, float]
    axis: str | None
    radius: float
    length: float = 0.0


def _cyl_x(x0: float, x1: float, r: float, z: float = 0.0) -> _Shape:
    return _Shape(((x0 + x1) / 2.0, 0.0, z), "x", r, x1 - x0)


def _link_shapes(d: KukaDimensions) -> dict[str, list[_Shape]]:
    """Simplified solids of each link; radii scale with the shoulder offset a1."""
    s = d.a1
    return {
        "base_link": [_Shape((0.0, 0.0, 0.2 * d.d1), "z", 0.85 * s, 0.4 * d.d1)],
        "link_1": [_Shape((0.0, 0.0, -0.3 * d.d1), "z", 0.75 * s, 0.6 * d.d1),
                   _Shape((d.a1, 0.0, 0.0), "y", 0.5 * s, 1.2 * s)],
        "link_2": [_cyl_x(0.0, d.a2, 0.35 * s)],
        "link_3": [_Shape((0.0, 0.0, 0.0), "y", 0.4 * s, s),
                   _cyl_x(-0.35 * s, 0.35 * d.d4, 0.3 * s, d.a3)],
        # The forearm is split at 0.35 d4 between link_3 and link_4, and link_4 ends
        # short of the wrist centre (the wrist sphere of link_5 covers it): so the
        # enclosing capsules of non-adjacent links (2-4, 4-6) do not overlap in
        # every pose, which would make those pairs impossible to constrain.
        "link_4": [_cyl_x(-0.65 * d.d4, -0.3 * s, 0.25 * s)],
        "link_5": [_Shape((0.0, 0.0, 0.0), None, 0.3 * s)],
        "link_6": [_cyl_x(0.5 * d.d6, d.d6, 0.2 * s)],
    }  # fmt: skip


def _mass(shape: _Shape) -> float:
    r = shape.radius
    volume = 4.0 / 3.0 * math.pi * r**3 if shape.axis is None else math.pi * r**2 * shape.length
    return _DENSITY * volume


def _inertial(shapes: list[_Shape]) -> tuple[float, list[float], list[list[float]]]:
    """Mass [kg], centre of mass [m] and inertia about it [kg m^2] of solid shapes."""
    masses = [_mass(sh) for sh in shapes]
    total = sum(masses)
    com = [
        sum(m * sh.centre[k] for m, sh in zip(masses, shapes, strict=True)) / total
        for k in range(3)
    ]
    inertia = [[0.0] * 3 for _ in range(3)]
    for m, sh in zip(masses, shapes, strict=True):
        r, length = sh.radius, sh.length
        if sh.axis is None:
            own = [0.4 * m * r**2] * 3
        else:
            own = [m * (3.0 * r**2 + length**2) / 12.0] * 3
            own["xyz".index(sh.axis)] = 0.5 * m * r**2
        off = [sh.centre[k] - com[k] for k in range(3)]
        dist2 = sum(v * v for v in off)
        for i in range(3):
            for j in range(3):
                inertia[i][j] += m * ((dist2 if i == j else 0.0) - off[i] * off[j])
            inertia[i][i] += own[i]
    return total, com, inertia


def _fe(x: float) -> str:
    """Exact, deterministic text of a float (shortest round-trip repr)."""
    x = float(x) + 0.0  # -0.0 -> 0.0
    text = repr(x)
    return text[:-2] if text.endswith(".0") else text


def _fa(x: float) -> str:
    """Approximate text of a derived quantity (6 significant digits)."""
    return f"{float(x) + 0.0:.6g}"


def _origin(xyz, rpy=(0.0, 0.0, 0.0), fmt=_fe) -> str:
    return f'<origin xyz="{" ".join(fmt(v) for v in xyz)}" rpy="{" ".join(_fe(v) for v in rpy)}"/>'


def _link_xml(name: str, shapes: list[_Shape]) -> list[str]:
    mass, com, inertia = _inertial(shapes)
    (ixx, ixy, ixz), (_, iyy, iyz), (_, _, izz) = inertia
    lines = [
        f'  <link name="{name}">',
        "    <inertial>",
        f"      {_origin(com, fmt=_fa)}",
        f'      <mass value="{_fa(mass)}"/>',
        f'      <inertia ixx="{_fa(ixx)}" ixy="{_fa(ixy)}" ixz="{_fa(ixz)}" '
        f'iyy="{_fa(iyy)}" iyz="{_fa(iyz)}" izz="{_fa(izz)}"/>',
        "    </inertial>",
    ]
    for sh in shapes:
        rpy = _AXIS_RPY[sh.axis or "z"]
        geom = (
            f'<sphere radius="{_fa(sh.radius)}"/>'
            if sh.axis is None
            else f'<cylinder radius="{_fa(sh.radius)}" length="{_fa(sh.length)}"/>'
        )
        for tag in ("visual", "collision"):
            material = '      <material name="kuka_orange"/>\n' if tag == "visual" else ""
            lines.append(
                f"    <{tag}>\n      {_origin(sh.centre, rpy, _fa)}\n"
                f"      <geometry>{geom}</geometry>\n{material}    </{tag}>"
            )
    return [*lines, "  </link>"]


def kuka_urdf(dims: KukaDimensions) -> str:
    """URDF text of ``dims`` in the layout of the module docstring; deterministic."""
    shapes = _link_shapes(dims)
    names = list(shapes)
    origins = [(0.0, 0.0, dims.d1), (dims.a1, 0.0, 0.0), (dims.a2, 0.0, 0.0),
               (dims.d4, 0.0, dims.a3), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)]  # fmt: skip
    # World x of joints A1..A6 at q = 0, and mass [kg] and world x of the centre of mass
    # of link_1..link_6 [m].
    xs = [0.0, dims.a1, dims.a1 + dims.a2] + [dims.a1 + dims.a2 + dims.d4] * 3
    inertials = [_inertial(shapes[n]) for n in names[1:]]
    masses = [m for m, _, _ in inertials]
    com_xs = [x + com[0] for x, (_, com, _) in zip(xs, inertials, strict=True)]
    # A notional payload at the flange, 10 % of the arm's mass, for the effort estimate.
    masses.append(0.1 * sum(masses))
    com_xs.append(dims.a1 + dims.a2 + dims.d4 + dims.d6)
    lines = [
        f"<!-- Generated by calib_oed.model.kuka from the dimensions of {dims.name!r}:",
        f"     d1={_fe(dims.d1)} a1={_fe(dims.a1)} a2={_fe(dims.a2)} a3={_fe(dims.a3)} "
        f"d4={_fe(dims.d4)} d6={_fe(dims.d6)} [m].",
        f"     Source: {dims.source.replace('--', '- -')}.",
        "     Simplified geometry and rough masses; do not edit, regenerate. -->",
        f'<robot name="{dims.name}">',
        '  <material name="kuka_orange"><color rgba="1 0.4 0 1"/></material>',
    ]
    for name in names:
        lines += _link_xml(name, shapes[name])
    lines += ['  <link name="flange"/>', '  <link name="tool0"/>']
    scale = KR16.reach / dims.reach
    for i in range(6):
        # Placeholders, calib_oed uses neither. Effort: twice the gravity torque of the
        # distal links and payload about a horizontal axis through the joint at q = 0 [N m];
        # velocity: KR 16 values, slower for longer arms [rad/s].
        lever = sum(m * abs(x - xs[i]) for m, x in zip(masses[i:], com_xs[i:], strict=True))
        effort = 2.0 * 9.81 * lever
        velocity = math.radians(_KR16_VELOCITY[i]) * min(1.0, scale)
        lines += [
            f'  <joint name="joint_a{i + 1}" type="revolute">',
            f'    <parent link="{names[i]}"/>',
            f'    <child link="{names[i + 1]}"/>',
            f"    {_origin(origins[i])}",
            f'    <axis xyz="{" ".join(str(v) for v in _JOINT_AXES[i])}"/>',
            f'    <limit lower="{_fe(dims.lower[i])}" upper="{_fe(dims.upper[i])}" '
            f'effort="{_fa(effort)}" velocity="{_fa(velocity)}"/>',
            "  </joint>",
        ]
    lines += [
        '  <joint name="joint_a6-flange" type="fixed">',
        '    <parent link="link_6"/>', '    <child link="flange"/>',
        f"    {_origin((dims.d6, 0.0, 0.0))}", "  </joint>",
        '  <joint name="flange-tool0" type="fixed">',
        '    <parent link="flange"/>', '    <child link="tool0"/>',
        f"    {_origin((0.0, 0.0, 0.0), (0.0, _HALF_PI, 0.0))}", "  </joint>",
        "</robot>",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def write_kuka_urdf(dims: KukaDimensions, path: str | os.PathLike[str]) -> Path:
    """Write :func:`kuka_urdf` to ``path`` atomically (temporary file, then rename)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
            f.write(kuka_urdf(dims))
        # mkstemp creates the file 0600; give it the mode of the file it replaces.
        os.chmod(tmp, path.stat().st_mode & 0o777 if path.exists() else 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
