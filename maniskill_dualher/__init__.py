"""maniskill_dualher: prioritized hindsight with a dual replay buffer (Beyene & Han 2022) on ManiSkill3.

Importing this package registers the ManiSkill tasks ReachTarget-v1, CloseBox-v1 and CloseMicrowave-v1.
"""
import warnings

# SAPIEN warns on import when the system has no usable libvulkan (CPU-only machines); it then works fine.
warnings.filterwarnings("ignore", message="Failed to find system libvulkan")

import tasks as _tasks  # noqa: F401  (registers the environments)

__version__ = "0.1.0"
