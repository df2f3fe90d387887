"""Wrappers that make ManiSkill's CPU gym interface aware of the ``hybrid`` render mode."""

from __future__ import annotations

from mani_skill.utils import common
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper as ManiSkillCPUGymWrapper


class CPUGymWrapper(ManiSkillCPUGymWrapper):
    """ManiSkill's ``CPUGymWrapper`` (one env, numpy in and out), also returning ``hybrid``
    frames from ``render()`` as an (H, W, 3) uint8 array; ManiSkill's returns None for modes it
    does not know."""

    def render(self):
        if self.render_mode == "hybrid":
            return common.unbatch(common.to_numpy(self.env.render()))
        return super().render()
