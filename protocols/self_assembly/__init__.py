"""Programmable self-assembly (Rubenstein, Cornejo and Nagpal, Science 345:795, 2014): the
rules as pure functions (:mod:`.rules`) and the robot program that runs them (:mod:`.program`).
"""

from kilonet.protocols.self_assembly.program import ASSEMBLY, AssemblyStage, SelfAssembly
from kilonet.protocols.self_assembly.rules import Shape

__all__ = ["ASSEMBLY", "AssemblyStage", "SelfAssembly", "Shape"]
