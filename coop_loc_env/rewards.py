"""Reward terms registered by name; a robot's reward is the sum of its terms.

Every step the env hands the terms one :class:`RewardInputs`; each term returns one
Python float per robot, already weighted. The reward adds them left to right from
0.0, in this order: the built-in terms (:data:`BUILTIN_TERMS`, always present, their
weights in the config's ``reward_*_weight`` / ``*_penalty`` fields), then the
config's ``extra_reward_terms`` and the other terms named in ``reward_weights``.
Infos report each as ``reward_<name>`` (and in ``reward_terms``).

A term has three phases: :meth:`RewardTerm.reset` at the start of an episode,
:meth:`RewardTerm.compute` (reads the inputs, changes nothing) and
:meth:`RewardTerm.advance` after every compute (a term with a reference, as the
uncertainty shaping's last ``0.5 log det P_xy``, moves it on here). A term from
outside the package::

    @register_reward_term("progress", default_weight=0.5)
    class Progress(RewardTerm):
        def compute(self, x):
            return [self.weight * float(v) for v in x.covered_cells.tolist()]

    env = coop_loc_env.parallel_env(extra_reward_terms=("progress",))
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class RewardInputs:
    """What the reward terms read at one step (every array one row per robot).

    ``err_xy`` / ``err_th``: true position (m) and heading (rad) errors; ``in_contact``:
    touching something this step (``None`` at reset); ``tipped``: newly tipped over
    (0/1); ``cov``: belief covariances ``(n, 3, 3)``; ``covered_cells``: drivable cells
    first covered at the true pose; ``active``: robots still in; ``env``: the env (for
    terms that read more).
    """

    err_xy: np.ndarray
    err_th: np.ndarray
    in_contact: np.ndarray | None
    tipped: np.ndarray
    cov: np.ndarray
    covered_cells: np.ndarray
    active: np.ndarray
    env: Any = None

    @classmethod
    def at_start(cls, cov: np.ndarray, active: np.ndarray, env: Any = None) -> RewardInputs:
        """The inputs of an episode's start (no error, contact or tip-over yet)."""
        n = len(cov)
        zeros = np.zeros(n)
        return cls(zeros, zeros, None, zeros, cov, np.zeros(n, dtype=np.int64), active, env)

    @functools.cached_property
    def half_logdet_xy(self) -> np.ndarray:
        """``0.5 log det`` of each covariance's position block, ``(n,)`` (computed once)."""
        return half_logdet_xy(self.cov)


class RewardTerm:
    """One reward term: ``compute`` returns each robot's weighted value.

    Built as ``cls(cfg, weight)``; ``weight`` comes from the config (see the module
    docstring). Override :meth:`reset` / :meth:`advance` for a term with state.
    """

    name: str = ""
    #: The weight of a registered term the config gives none in ``reward_weights``.
    default_weight: float = 1.0

    def __init__(self, cfg: Any, weight: float) -> None:
        self.cfg = cfg
        self.weight = weight
        self.n = cfg.n_robots

    def reset(self, x: RewardInputs) -> None:
        """Start of an episode (``x`` holds the start's beliefs; no reward yet)."""

    def compute(self, x: RewardInputs) -> list[float]:
        """One weighted Python float per robot."""
        raise NotImplementedError

    def advance(self, x: RewardInputs) -> None:
        """After :meth:`compute` on the same inputs: move any reference on."""


#: Reward term name -> class (built as ``cls(cfg, weight)``), in registration order.
REWARD_TERMS: dict[str, type[RewardTerm]] = {}


def register_reward_term(name: str, cls: type[RewardTerm] | None = None,
                         default_weight: float | None = None) -> Any:
    """Make ``cls`` available as reward term ``name`` (a class decorator without ``cls``).

    ``default_weight`` sets the class's :attr:`RewardTerm.default_weight`.
    """
    def register(klass: type[RewardTerm]) -> type[RewardTerm]:
        if not (isinstance(klass, type) and issubclass(klass, RewardTerm)):
            raise ValueError(f"reward term {name!r} must be a RewardTerm subclass, got {klass!r}")
        klass.name = name
        if default_weight is not None:
            klass.default_weight = float(default_weight)
        REWARD_TERMS[name] = klass
        return klass

    return register if cls is None else register(cls)


class Localization(RewardTerm):
    """Minus the weighted position and heading errors."""

    def compute(self, x: RewardInputs) -> list[float]:
        w_loc, w_head = self.cfg.reward_localization_weight, self.cfg.reward_heading_weight
        return [-w_loc * exy - w_head * eth
                for exy, eth in zip(x.err_xy.tolist(), x.err_th.tolist(), strict=True)]


class Coverage(RewardTerm):
    """The weighted number of drivable cells first covered at the true pose."""

    def __init__(self, cfg: Any, weight: float) -> None:
        super().__init__(cfg, weight)
        self.w_cov = cfg.reward_coverage_weight
        self.zeros = [0.0] * self.n  # the term with weight 0 (cells count from 0 up)

    def compute(self, x: RewardInputs) -> list[float]:
        w_cov = self.w_cov
        if not w_cov:
            return self.zeros
        return [w_cov * float(c) for c in x.covered_cells.tolist()]


class Collision(RewardTerm):
    """Minus ``collision_penalty`` on every step spent touching something."""

    def compute(self, x: RewardInputs) -> list[float]:
        pen_hit = -self.cfg.collision_penalty
        touching = [False] * self.n if x.in_contact is None else x.in_contact.tolist()
        return [pen_hit * float(t) for t in touching]


class TipOver(RewardTerm):
    """Minus ``tip_over_penalty`` on the step a robot tips over."""

    def compute(self, x: RewardInputs) -> list[float]:
        pen_tip = -self.cfg.tip_over_penalty
        return [pen_tip * t for t in x.tipped.tolist()]


class TeamLocalization(RewardTerm):
    """Minus ``reward_team_weight`` times the live robots' mean position error (shared)."""

    def compute(self, x: RewardInputs) -> list[float]:
        w = self.cfg.reward_team_weight
        team_term = -w * float(x.err_xy[x.active].mean()) if (w and x.active.any()) else 0.0
        return [team_term] * self.n


class Uncertainty(RewardTerm):
    """Minus ``reward_uncertainty_weight`` times the change of ``0.5 log det P_xy``.

    The reference (:attr:`half_logdet`) is set at :meth:`reset` and moved to the
    current value at :meth:`advance`; with weight 0 the term is 0.0, uncomputed.
    """

    def __init__(self, cfg: Any, weight: float) -> None:
        super().__init__(cfg, weight)
        self.half_logdet = np.zeros(self.n)  # each robot's 0.5 log det P_xy, last step

    def reset(self, x: RewardInputs) -> None:
        self.half_logdet = x.half_logdet_xy

    def compute(self, x: RewardInputs) -> list[float]:
        w = self.cfg.reward_uncertainty_weight
        if not w:
            return [0.0] * self.n
        return (-w * (x.half_logdet_xy - self.half_logdet)).tolist()

    def advance(self, x: RewardInputs) -> None:
        if self.cfg.reward_uncertainty_weight:
            self.half_logdet = x.half_logdet_xy


#: The terms every env has, in the order the reward adds them.
BUILTIN_TERMS = ("localization", "coverage", "collision", "tip_over", "team_localization",
                 "uncertainty")
for _name, _cls in zip(BUILTIN_TERMS, (Localization, Coverage, Collision, TipOver,
                                       TeamLocalization, Uncertainty), strict=True):
    register_reward_term(_name, _cls)


def extra_term_names(cfg: Any) -> tuple[str, ...]:
    """The config's terms beyond the built-ins: ``extra_reward_terms``, then the other
    names in ``reward_weights`` (in their order)."""
    names = dict.fromkeys(cfg.extra_reward_terms)
    names.update(dict.fromkeys(cfg.reward_weights))
    return tuple(names)


def check_reward_config(extra_terms: Any, weights: Any) -> None:
    """Raise ``ValueError`` naming the entry on a bad ``extra_reward_terms`` /
    ``reward_weights`` (unregistered, built-in, or a weight that is not a finite number)."""
    if not isinstance(extra_terms, tuple) or not all(isinstance(t, str) for t in extra_terms):
        raise ValueError(f"extra_reward_terms must be a list of term names, got {extra_terms!r}")
    if not isinstance(weights, dict):
        raise ValueError(f"reward_weights must be a dict term name -> weight, got {weights!r}")
    for name in (*extra_terms, *weights):
        if name in BUILTIN_TERMS:
            raise ValueError(f"reward term {name!r} is built in: its weight is a config field "
                             "(reward_*_weight, *_penalty)")
        if name not in REWARD_TERMS:
            raise ValueError(f"unknown reward term {name!r}; registered: "
                             f"{', '.join(REWARD_TERMS)} (register_reward_term)")
    for name, weight in weights.items():
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (
                np.isfinite(weight)):
            raise ValueError(f"reward_weights[{name!r}] must be a finite number, got {weight!r}")


class RewardTerms:
    """The terms of one env, in order; runs their phases."""

    def __init__(self, cfg: Any) -> None:
        self.terms: list[RewardTerm] = [REWARD_TERMS[name](cfg, 1.0) for name in BUILTIN_TERMS]
        for name in extra_term_names(cfg):
            cls = REWARD_TERMS[name]
            self.terms.append(cls(cfg, float(cfg.reward_weights.get(name, cls.default_weight))))
        self.names = [term.name for term in self.terms]
        self._stateful = [t for t in self.terms if type(t).advance is not RewardTerm.advance]
        self._computes = [(term.name, term.compute) for term in self.terms]

    def reset(self, x: RewardInputs) -> None:
        """Start of an episode: every term's :meth:`RewardTerm.reset`."""
        for term in self.terms:
            term.reset(x)

    def compute(self, x: RewardInputs) -> dict[str, list[float]]:
        """``{term name: one weighted float per robot}`` in the reward's order."""
        return {name: compute(x) for name, compute in self._computes}

    def advance(self, x: RewardInputs) -> None:
        """The step's last reward phase: the terms with a reference move it on."""
        for term in self._stateful:
            term.advance(x)


def sum_terms(terms: dict[str, list[float]]) -> list[float]:
    """Each robot's reward: its terms added left to right from 0.0 (not ``sum()``, whose
    compensated float summation could differ in the last bit)."""
    totals = [0.0] * len(next(iter(terms.values())))
    for values in terms.values():
        totals = [total + v for total, v in zip(totals, values, strict=True)]
    return totals


def half_logdet_xy(cov: np.ndarray) -> np.ndarray:
    """``0.5 log det`` of each ``(3, 3)`` covariance's position block, ``(n,)``."""
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]
    return 0.5 * np.log(np.maximum(det, 1e-300))

