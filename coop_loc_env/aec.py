"""The AEC version of the environment: PettingZoo's ``parallel_to_aec`` conversion, with
each agent's action checked when it is given."""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from coop_loc_env.actions import check_action
from coop_loc_env.env import CoopLocParallelEnv


class CoopLocAECEnv(parallel_to_aec_wrapper):
    """AEC view of a :class:`CoopLocParallelEnv`.

    PettingZoo's conversion buffers the actions and steps the parallel env at
    the last agent, so a bad action of the first agent would surface only
    then, and stay in the buffer. Here :meth:`step` refuses a bad action with
    a ``ValueError`` before buffering it: the same agent is still to act, and
    the env stays usable.
    """

    env: CoopLocParallelEnv

    def step(self, action: Any) -> None:
        """Buffer the selected agent's action (``None`` for an agent that is done)."""
        if getattr(self, "_agent_selector", None) is None:
            raise ValueError("step() called before reset(): call reset() first")
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            if action is not None:
                raise ValueError(
                    f"agent {agent!r} is done: its action must be None, got {action!r}"
                )
        else:
            check_action(agent, action)
        super().step(action)
