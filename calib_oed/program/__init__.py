"""Measurement programs: the design's poses ordered for the shortest cycle, every move
certified collision-free, blocked moves through planned via points, written in a
controller's language (docs/program.md)."""

from calib_oed.program.build import build_program
from calib_oed.program.formats import FORMATS, program_texts, write_program
from calib_oed.program.records import Move, Program
from calib_oed.program.settings import ProgramSettings, program_settings_from_scene

__all__ = ["FORMATS", "Move", "Program", "ProgramSettings", "build_program", "program_settings_from_scene",
           "program_texts", "write_program"]
