r"""How a measurement program is timed, checked and planned: :class:`ProgramSettings`.

The defaults are what a calibration engineer would start with; a scene may
override them in an optional ``program:`` block (in the file's units):

.. code-block:: yaml

    program:
      home: [0, -90, 90, 0, 0, 0]        # joint angles; default: the KPI's first working configuration
      dwell: 2.0                         # [s] settle + tracker measurement at every pose
      velocity_scale: 1.0                # fraction of the URDF <limit velocity> used (0, 1]
      acceleration_time: 0.5             # [s] from standstill to full speed, per joint
      velocities: {joint_a1: 120}        # angle units / s, replaces the URDF's limit
      accelerations: {joint_a1: 240}     # angle units / s², replaces velocity / acceleration_time
      move_tolerance: 1                  # length unit: clearance margin a move may use up

Everything in a :class:`ProgramSettings` is SI [m, rad, s].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.scene.fields import FieldReader
from calib_oed.units import ANGLE_UNITS, LENGTH_UNITS

#: Keys of the scene's ``program:`` block.
PROGRAM_KEYS = ("home", "dwell", "velocity_scale", "acceleration_time", "velocities",
                "accelerations", "move_tolerance", "planner_iterations", "handshake", "tool", "base",
                "payload")


@dataclass(frozen=True, eq=False)
class FrameSpec:
    """A tool frame (in the flange frame) or base/user frame (in the robot base frame) the
    program declares, with its number on the controller.

    Attributes:
        number: The controller's tool/base (user frame) number, >= 1.
        xyz: Origin [m], (3,).
        rpy: Roll, pitch, yaw [rad], :math:`R = R_z(y) R_y(p) R_x(r)` (KUKA's A = y, B = p, C = r).
    """

    number: int = 1
    xyz: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True, eq=False)
class PayloadSpec:
    """The load on the flange during the program (the reflector nest): mass and centre of mass.

    Attributes:
        mass: [kg], >= 0.
        com: Centre of mass in the flange frame [m], (3,).
        number: The controller's payload schedule number (FANUC ``PAYLOAD[n]``), >= 1.
    """

    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    number: int = 1


@dataclass(frozen=True)
class Handshake:
    """What the controller does at each measurement pose instead of the blind dwell.

    Either a signal exchange with the tracker's software (``output`` set, wait until
    ``input`` is on, ``output`` reset) or a call of a routine on the controller that
    does its own (``routine``). Signals are numbers (KRL ``$OUT[n]``/``$IN[n]``, TP
    ``DO[n]``/``DI[n]``, URScript digital outputs/inputs) or, for RAPID, signal names
    (``do<n>``/``di<n>`` unless ``output_name``/``input_name`` are given).

    Attributes:
        output: Digital output set when the pose is reached, or ``None``.
        input: Digital input waited for (on), or ``None``.
        routine: Name of a routine called instead, or ``None``.
        output_name, input_name: RAPID's signal names (default ``do<output>``, ``di<input>``).
    """

    output: int | None = None
    input: int | None = None
    routine: str | None = None
    output_name: str | None = None
    input_name: str | None = None

    def __post_init__(self):
        if (self.routine is None) == (self.output is None or self.input is None):
            raise ProgramError("handshake", vars(self), "give either output and input (signal "
                               "numbers) or routine (a routine name)")
        if self.routine is not None and not self.routine.isidentifier():
            raise ProgramError("handshake.routine", self.routine, "a routine name must be an identifier")

    @property
    def signal_names(self) -> tuple[str, str]:
        """The output's and the input's names (RAPID's signals): ``output_name``/``input_name``,
        default ``do<output>``/``di<input>``."""
        return self.output_name or f"do{self.output}", self.input_name or f"di{self.input}"


#: RRT-Connect iterations per blocked move (:func:`calib_oed.program.planner.plan_move`).
DEFAULT_PLANNER_ITERATIONS = 20_000


@dataclass(frozen=True, eq=False)
class ProgramSettings:
    """Timing, collision-check and planner settings of a measurement program.

    Attributes:
        home: Home configuration [rad], (nq,), where the program starts and ends; ``None``:
            the scene's first KPI working configuration.
        dwell: Settle and measure time at every measurement pose [s] (2 s).
        velocity_scale: Fraction of each joint's velocity limit a move uses, in (0, 1].
        acceleration_time: Time [s] a joint takes from standstill to its (scaled) velocity
            limit when no acceleration is given: :math:`a_i = v_i / t_{acc}` (0.5 s, a
            documented default: URDFs carry no acceleration limits).
        velocities: Per-joint velocity limits [rad/s] replacing the URDF's, by joint name.
        accelerations: Per-joint acceleration limits [rad/s²], by joint name.
        move_tolerance: How much of the design's clearance margin a move may use up [m]
            (1 mm): every move keeps each capsule row :math:`g \\ge -\\delta`, i.e. at least
            ``margins.clearance - move_tolerance`` of true clearance; the measurement poses
            keep the full margin.
        planner_iterations: Budget of the motion planner per blocked move, in RRT-Connect
            iterations (not seconds: the same input gives the same program under any load).
        planner_seed: Seed of the planner's random samples.
        handshake: A signal exchange or routine call at each measurement pose instead of the
            dwell (:class:`Handshake`), or ``None`` (the dwell).
        tool, base: The tool frame and base/user frame the program declares
            (:class:`FrameSpec`), or ``None`` (the controller's current ones).
        payload: The load the program declares (:class:`PayloadSpec`); default the scene's
            ``robot.compliance.payload`` when compliance is modelled (``enabled``), else ``None``
            (a disabled block's payload is a rated load kept for ``--compliance``, not the nest).
        skip_unreachable: Leave out (with a note) a pose no certified path from home reaches
            (else a :class:`~calib_oed.exceptions.ProgramError` names it).
        wrap: Measure each pose at the joint values a whole number of turns away that are
            nearest home, on joints whose range allows it (the same robot geometry; a
            different measurement only for a model with non-periodic joint terms).
    """

    home: np.ndarray | None = None
    dwell: float = 2.0
    velocity_scale: float = 1.0
    acceleration_time: float = 0.5
    velocities: dict = field(default_factory=dict)
    accelerations: dict = field(default_factory=dict)
    move_tolerance: float = 0.001
    planner_iterations: int = DEFAULT_PLANNER_ITERATIONS
    planner_seed: int = 0
    handshake: Handshake | None = None
    tool: FrameSpec | None = None
    base: FrameSpec | None = None
    payload: PayloadSpec | None = None
    skip_unreachable: bool = True
    wrap: bool = False

    def __post_init__(self):
        if (isinstance(self.planner_iterations, bool) or int(self.planner_iterations) != self.planner_iterations
                or self.planner_iterations < 1):
            raise ProgramError("planner_iterations", self.planner_iterations, "expected an integer >= 1")
        for name in ("dwell", "acceleration_time", "move_tolerance"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0 or (name == "acceleration_time" and value == 0):
                raise ProgramError(name, value, "expected a finite number > 0 (dwell, "
                                   "move_tolerance: >= 0)")
        if not 0 < self.velocity_scale <= 1:
            raise ProgramError("velocity_scale", self.velocity_scale, "expected a number in (0, 1]")
        for name in ("velocities", "accelerations"):
            for joint, value in getattr(self, name).items():
                if not (np.isfinite(value) and value > 0):
                    raise ProgramError(f"{name}.{joint}", value, "expected a number > 0")



def program_settings_from_scene(scene, **overrides) -> ProgramSettings:
    """The settings of a scene's ``program:`` block (defaults where absent), then ``overrides``.

    Raises:
        SceneError: an unknown key, a bad value or an unknown joint, naming the key.
    """
    block = getattr(scene, "program", None) or {}
    reader = FieldReader(str(scene.source) if scene.source else None)
    reader.length = LENGTH_UNITS[scene.units.get("length", "m")]
    reader.angle = ANGLE_UNITS[scene.units.get("angle", "rad")]
    spec = reader.mapping(block, "program", (), PROGRAM_KEYS)
    robot = scene.robot
    joints = list(robot.joint_names)
    values: dict = {}
    if "home" in spec:
        values["home"] = reader.vector(spec["home"], "program.home", len(joints), reader.angle,
                                       what="one per joint: " + ", ".join(joints))
    for key in ("dwell", "acceleration_time", "velocity_scale"):
        if key in spec:
            values[key] = reader.number(spec[key], f"program.{key}", positive=key != "dwell",
                                        nonnegative=True)
    if "move_tolerance" in spec:
        values["move_tolerance"] = reader.number(spec["move_tolerance"], "program.move_tolerance",
                                                 reader.length, nonnegative=True)
    for key in ("velocities", "accelerations"):
        table = reader.free_mapping(spec.get(key, {}), f"program.{key}")
        for joint in table:
            if joint not in joints:
                raise reader.fail(f"program.{key}.{joint}", "unknown joint; the robot's joints "
                                  f"are: {', '.join(joints)}")
        if table:
            values[key] = {j: reader.number(v, f"program.{key}.{j}", reader.angle, positive=True)
                           for j, v in table.items()}
    if "planner_iterations" in spec:
        values["planner_iterations"] = reader.integer(spec["planner_iterations"],
                                                      "program.planner_iterations", 1)
    if "handshake" in spec:
        hs = reader.mapping(spec["handshake"], "program.handshake", (),
                            ("output", "input", "routine", "output_name", "input_name"))
        for key in ("output", "input"):
            if key in hs:
                hs[key] = reader.integer(hs[key], f"program.handshake.{key}", 0)
        for key in ("routine", "output_name", "input_name"):
            if key in hs:
                hs[key] = reader.string(hs[key], f"program.handshake.{key}")
        try:
            values["handshake"] = Handshake(**hs)
        except ProgramError as exc:
            raise reader.fail("program.handshake", str(exc)) from None
    for key in ("tool", "base"):
        if key in spec:
            fr = reader.mapping(spec[key], f"program.{key}", (), ("number", "xyz", "rpy"))
            values[key] = FrameSpec(
                reader.integer(fr.get("number", 1), f"program.{key}.number", 1),
                reader.vector(fr.get("xyz", [0, 0, 0]), f"program.{key}.xyz", 3, reader.length),
                reader.vector(fr.get("rpy", [0, 0, 0]), f"program.{key}.rpy", 3, reader.angle))
    if "payload" in spec:
        pl = reader.mapping(spec["payload"], "program.payload", ("mass",), ("com", "number"))
        values["payload"] = PayloadSpec(
            reader.number(pl["mass"], "program.payload.mass", nonnegative=True),
            reader.vector(pl.get("com", [0, 0, 0]), "program.payload.com", 3, reader.length),
            reader.integer(pl.get("number", 1), "program.payload.number", 1))
    elif getattr(scene, "compliance", None) is not None and scene.compliance.enabled:
        load = scene.compliance.payload  # the load of the compliance model, on during the measurements
        values["payload"] = PayloadSpec(float(load.payload_mass), np.asarray(load.payload_com, float))
    if "velocity_scale" in values and values["velocity_scale"] > 1:
        raise reader.fail("program.velocity_scale", f"expected a number in (0, 1], got "
                          f"{values['velocity_scale']!r}")
    values.update({k: v for k, v in overrides.items() if v is not None})
    return ProgramSettings(**values)
