"""Scripted controllers, and the registry of policy names (:mod:`policies.scripted.registry`).

Every policy here follows :class:`~policies.scripted.baselines.Policy`
(``reset(env, seed)``, ``act(obs)``). Besides the baselines
(:mod:`~policies.scripted.baselines`: ``random``, ``seek``, ``still``) and
Madhavan et al.'s traversal state machine (:mod:`~policies.scripted.fsm`,
``fsm``), the reactive behaviours of the papers' experiments read only the
robot's own scan (:class:`~policies.scripted.view.ScanView`):
:class:`~policies.scripted.wander.WanderPolicy` (``wander``, Fox et al.),
:class:`~policies.scripted.dispersal.DispersalPolicy` and
:class:`~policies.scripted.circuit.CircuitPolicy` (Howard et al.; the circuit's
driver steers by its true pose, a stand-in for a human driver).

The active-localization baselines drive where the team's beliefs say information is:

* :class:`~policies.scripted.gather.GatherPolicy` (``gather``): drive toward the
  communicated estimates of the teammates that can inform you (GPS-equipped
  ones for a robot without GPS, and the other way round).
* :class:`~policies.scripted.infogain.InfoGainPolicy` (``infogain``): greedy
  information seeking over a few motion primitives, minimizing the team's
  expected posterior log det covariance over a short horizon; robots that run
  MCL minimize instead the expected posterior entropy over pose hypotheses
  drawn from their particles
  (:class:`~policies.scripted.infogain_mcl.MCLInfoGainPlanner`, active Markov
  localization).
* :class:`~policies.scripted.corridor.CorridorPolicy` (``corridor``): follow
  the free space ahead at full speed by the robot's own scan (exploration for
  global localization; needs no belief).
* :class:`~policies.scripted.hypothesis.HypothesisPolicy` (``hypothesis``):
  hypothesis elimination with far targets: drive by a geodesic path to where
  the modes of the particle belief predict different readings; localized
  robots drive to meet the lost ones.

They read only beliefs (means and covariances the team shares, particle sets),
the robot's own range readings and odometry, the static map (obstacles, tree
canopies) and the robots' hardware (which ones carry GPS); never the true poses.
"""

from policies.scripted.corridor import CorridorPolicy
from policies.scripted.gather import GatherPolicy
from policies.scripted.hypothesis import HypothesisPolicy
from policies.scripted.infogain import InfoGainPolicy

__all__ = ["CorridorPolicy", "GatherPolicy", "HypothesisPolicy", "InfoGainPolicy"]
