"""The three Panda tasks of the paper, rebuilt as ManiSkill3 environments (registered on import).

Each task module registers its env id with ManiSkill/gymnasium when imported; add new tasks here.
"""
import warnings

# SAPIEN warns on import when the system has no usable libvulkan (CPU-only machines); it then works fine.
warnings.filterwarnings("ignore", message="Failed to find system libvulkan")

from . import reach_target  # noqa: F401  (ReachTarget-v1)
from . import close_box  # noqa: F401  (CloseBox-v1)
from . import close_microwave  # noqa: F401  (CloseMicrowave-v1)
