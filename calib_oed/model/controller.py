r"""Controller joint conventions: the affine map between controller joint values and URDF joints.

A robot controller reports and takes joint values in its own convention: a
joint may count the other way (sign), from another zero (offset), with a gear
ratio (scale), and some arms couple axes. FANUC controllers report J3 relative
to the horizontal, not to the upper arm: the URDF angle of joint 3 is
:math:`J_3 + J_2` (ROS-Industrial's ``fanuc_driver``: parameter ``J23_factor``,
``linkage_transform``: ``J3_out = J3_in + J23_factor * J2_in``, factor 1 for the
arms with the J2/J3 linkage; github.com/ros-industrial/fanuc).

With :math:`c \in \mathbb{R}^n` the controller values and :math:`q \in
\mathbb{R}^n` the URDF joint values, both SI [rad] (prismatic [m]),

.. math::

    q = A c + b, \qquad
    A = \mathrm{diag}(s_i k_i) + \sum_{(j, f, r)} r\, s_j k_j\, e_j e_f^\top, \qquad
    b_i = o_i,

with sign :math:`s_i \in \{-1, 1\}`, scale :math:`k_i > 0` and offset
:math:`o_i` [rad] of joint :math:`i`, and a coupling :math:`(j, f, r)` adding
:math:`r\,c_f` to joint :math:`j`'s controller value before its sign and scale
(so FANUC's ``{joint: 3, from: 2, ratio: 1}`` with unit signs gives
:math:`q_3 = c_3 + c_2`). The inverse is :math:`c = A^{-1}(q - b)`;
:math:`A` must be invertible. Joints are numbered from 1 here, as on a
controller (J1..Jn), and in the scene block.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib_oed.exceptions import SceneError
from calib_oed.units import ANGLE_UNITS

_BLOCK_KEYS = ("name", "angle", "joints", "couplings")
_JOINT_KEYS = ("sign", "offset", "scale")
_COUPLING_KEYS = ("joint", "from", "ratio")


@dataclass(frozen=True)
class Coupling:
    """Controller value ``source`` times ``ratio`` added to joint ``joint``'s (both 1-based)."""

    joint: int
    source: int
    ratio: float


@dataclass(frozen=True, eq=False)
class ControllerConvention:
    r"""The map :math:`q = A c + b` between controller values :math:`c` and URDF joints :math:`q`.

    Attributes:
        name: The controller's name (``fanuc``, ``kuka``, ...), written in file headers.
        angle: The unit the controller speaks, ``"deg"`` or ``"rad"``; used when
            writing designs and programs in controller values.
        sign: Per joint :math:`s_i \in \{-1, 1\}`, shape (n,).
        scale: Per joint :math:`k_i > 0`, shape (n,).
        offset: Per joint :math:`o_i`, shape (n,) [rad] (prismatic [m]).
        couplings: The linear couplings, each a :class:`Coupling`.
    """

    name: str
    angle: str
    sign: np.ndarray
    scale: np.ndarray
    offset: np.ndarray
    couplings: tuple[Coupling, ...] = field(default=())

    def __post_init__(self):
        n = len(self.sign)
        for key in ("sign", "scale", "offset"):
            arr = np.array(getattr(self, key), dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise SceneError(f"expected {n} finite numbers, got {getattr(self, key)!r}",
                                 key=f"controller.joints[].{key}")
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)
        if self.angle not in ANGLE_UNITS:
            raise SceneError(f"expected one of {', '.join(ANGLE_UNITS)}, got {self.angle!r}",
                             key="controller.angle")
        object.__setattr__(self, "couplings", tuple(self.couplings))
        a = self.matrix
        if abs(np.linalg.det(a)) < 1e-12:
            raise SceneError("the couplings make the map singular (no inverse); check the "
                             "ratios", key="controller.couplings")
        a.setflags(write=False)
        object.__setattr__(self, "_a", a)
        object.__setattr__(self, "_a_inv", np.linalg.inv(a))

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.sign)

    @property
    def matrix(self) -> np.ndarray:
        """:math:`A`, shape (n, n)."""
        d = self.sign * self.scale
        a = np.diag(d)
        for c in self.couplings:
            a[c.joint - 1, c.source - 1] += c.ratio * d[c.joint - 1]
        return a

    @property
    def unit_scale(self) -> float:
        """Controller angle unit in [rad] (1 for ``rad``, pi/180 for ``deg``)."""
        return ANGLE_UNITS[self.angle]

    def to_model(self, c: np.ndarray) -> np.ndarray:
        """URDF joints :math:`q = A c + b` [rad] from controller values ``c`` [rad], shape (n,) or (m, n)."""
        c = self._check(c)
        return c @ self._a.T + self.offset

    def to_controller(self, q: np.ndarray) -> np.ndarray:
        """Controller values :math:`c = A^{-1}(q - b)` [rad] from URDF joints ``q`` [rad], (n,) or (m, n)."""
        q = self._check(q)
        return (q - self.offset) @ self._a_inv.T

    def describe(self) -> str:
        """One line stating the convention, for file headers."""
        parts = [f"q{i + 1} = {'-' if s < 0 else ''}{k:g}*c{i + 1}" +
                 (f" + {math.degrees(o):g} deg" if o else "")
                 for i, (s, k, o) in enumerate(zip(self.sign, self.scale, self.offset, strict=True))
                 if s != 1 or k != 1 or o]
        parts += [f"c{c.joint} -> c{c.joint} + {c.ratio:g}*c{c.source} before its sign and scale"
                  for c in self.couplings]
        return (f"controller {self.name} (q = A c + b: "
                f"{'; '.join(parts) if parts else 'identity'})")

    def _check(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape[-1:] != (self.n,) or x.ndim > 2:
            raise ValueError(f"expected joint values of shape (n,) or (m, n) with n = {self.n}, "
                             f"got {x.shape}")
        return x


def _number(value: Any, key: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SceneError(f"expected a finite number, got {value!r}", key=key)
    if positive and value <= 0:
        raise SceneError(f"expected a number > 0, got {value!r}", key=key)
    return float(value)


def _mapping(value: Any, key: str, allowed: Sequence[str]) -> Mapping:
    if not isinstance(value, Mapping):
        raise SceneError(f"expected a mapping with keys {', '.join(allowed)}, got {value!r}", key=key)
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise SceneError(f"unknown key(s) {', '.join(map(str, unknown))}; valid keys are "
                         f"{', '.join(allowed)}", key=key)
    return value


def controller_from_mapping(data: Any, n: int, key: str = "controller") -> ControllerConvention:
    """Read a scene's ``controller:`` block for a robot with ``n`` joints (errors name the key).

    ``{name: fanuc, angle: deg, joints: [{sign: 1, offset: 0, scale: 1}, ...],
    couplings: [{joint: 3, from: 2, ratio: 1.0}]}``: ``joints`` has one entry
    per joint (each key optional: sign 1, offset 0, scale 1; offsets in
    ``angle`` units), or is omitted (identity); ``angle`` defaults to ``deg``.
    """
    block = _mapping(data, key, _BLOCK_KEYS)
    name = block.get("name", "controller")
    if not isinstance(name, str) or not name.strip():
        raise SceneError(f"expected a non-empty name, got {name!r}", key=f"{key}.name")
    angle = block.get("angle", "deg")
    if angle not in ANGLE_UNITS:
        raise SceneError(f"expected one of {', '.join(ANGLE_UNITS)}, got {angle!r}", key=f"{key}.angle")
    unit = ANGLE_UNITS[angle]
    joints = block.get("joints", [{}] * n)
    if not isinstance(joints, list) or len(joints) != n:
        raise SceneError(f"expected a list of {n} entries (one per joint), got {joints!r}",
                         key=f"{key}.joints")
    sign, scale, offset = [], [], []
    for i, entry in enumerate(joints):
        where = f"{key}.joints[{i + 1}]"
        entry = _mapping(entry, where, _JOINT_KEYS)
        s = entry.get("sign", 1)
        if isinstance(s, bool) or s not in (1, -1):
            raise SceneError(f"expected 1 or -1, got {s!r}", key=f"{where}.sign")
        sign.append(float(s))
        scale.append(_number(entry.get("scale", 1.0), f"{where}.scale", positive=True))
        offset.append(_number(entry.get("offset", 0.0), f"{where}.offset") * unit)
    couplings = []
    raw = block.get("couplings", [])
    if not isinstance(raw, list):
        raise SceneError(f"expected a list, got {raw!r}", key=f"{key}.couplings")
    for m, entry in enumerate(raw):
        where = f"{key}.couplings[{m + 1}]"
        entry = _mapping(entry, where, _COUPLING_KEYS)
        ids = []
        for k in ("joint", "from"):
            v = entry.get(k)
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= n:
                raise SceneError(f"expected a joint number 1..{n}, got {v!r}", key=f"{where}.{k}")
            ids.append(v)
        if ids[0] == ids[1]:
            raise SceneError(f"joint and from must differ, both are {ids[0]}", key=where)
        couplings.append(Coupling(ids[0], ids[1], _number(entry.get("ratio", 1.0), f"{where}.ratio")))
    return ControllerConvention(name.strip(), angle, np.array(sign), np.array(scale),
                                np.array(offset), tuple(couplings))
