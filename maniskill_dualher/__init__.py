"""maniskill_dualher: prioritized hindsight with a dual replay buffer (Beyene & Han 2022) on ManiSkill3.

``import maniskill_dualher.tasks`` registers the ManiSkill tasks ReachTarget-v1, CloseBox-v1 and
CloseMicrowave-v1 (as ``import mani_skill.envs`` registers ManiSkill's own); the commands and ``envs.make_env``
do it. Importing the package itself loads nothing heavy, so the analysis runs without torch or the simulator.
"""
import os
import warnings

# SAPIEN warns on import when the system has no usable libvulkan (CPU-only machines); it then works fine.
warnings.filterwarnings("ignore", message="Failed to find system libvulkan")

# The repository keeps tasks/ and baselines/ beside this package (the project's layout); installed, they
# live inside it (pyproject's package-dir). Either way they import as maniskill_dualher.tasks and
# maniskill_dualher.baselines, never as top-level `tasks` / `baselines` (names other projects use).
_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if os.path.isfile(os.path.join(_root, "tasks", "__init__.py")):
    __path__.append(_root)  # type: ignore[name-defined]  # a source checkout
del _root

__version__ = "0.1.0"
