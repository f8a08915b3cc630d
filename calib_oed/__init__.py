"""calib_oed: optimum experimental design for robot kinematic calibration."""

from calib_oed.robot import Robot, load_robot

__all__ = ["Robot", "load_robot"]
__version__ = "0.1.0"
