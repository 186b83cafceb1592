"""The three Panda tasks of the paper, rebuilt as ManiSkill3 environments (registered on import)."""
