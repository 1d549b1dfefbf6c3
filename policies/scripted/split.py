"""``split``: a team planner that sends the lost robots to different places that tell their
hypotheses apart, and the localized ones to meet them.

It is :class:`~policies.scripted.hypothesis.HypothesisPolicy` (particle modes, the
expected eliminated mass at every place of the known map, geodesic paths) with
greedy targets (``select="nearest"``: the nearest place whose gain reaches half the
best) and a team assignment: a lost robot's candidate places within ``ASSIGN_M`` of
the place any teammate is driving to -- every teammate's current target, not only those
chosen earlier in the same step -- cost ``SPLIT_PENALTY`` of gain (so with
``select="nearest"`` they come last), when both lead poses are within detector
range (so that the frames agree; a team dropped together shares its hypotheses, and
its robots fan out to different candidate places). A robot that becomes confident on
its own readings drives to meet the lost teammates (as ``hypothesis``), so a
detection passes its belief on.

Reads the particle beliefs, the known map, the robot's own scan and the team's
communicated beliefs; never the true poses.
"""

from __future__ import annotations

from policies.scripted.hypothesis import HypothesisPolicy

SPLIT_PENALTY = 1.0  # gain a place a teammate is driving to loses (the whole range of gains)


class SplitPolicy(HypothesisPolicy):
    """Hypothesis testing with the lost robots split over different places (module doc)."""

    name = "split"

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("select", "nearest")
        kwargs.setdefault("assign_penalty", SPLIT_PENALTY)
        kwargs.setdefault("copies", True)
        super().__init__(**kwargs)

    def _teammate_targets(self, i: int, targets: list) -> list:
        """Every teammate's current place (this step's new choices and the kept ones)."""
        out = list(targets)
        for j, st in self.state.items():
            if j != i and st.target is not None and st.lead is not None:
                out.append((st.lead, st.target))
        return out
