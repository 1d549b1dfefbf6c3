"""Named scenarios: registry, lookup and keyword overrides.

A scenario is a function returning a :class:`~coop_loc_env.config.ScenarioConfig`
from a dict of overrides, or a :class:`Scenario` that carries behaviour beside its
config (the observation blocks and reward terms it adds, a hook run at every
reset). :func:`make_config` looks one up by name and applies the overrides
(unknown keys and invalid values raise ``ValueError``).

Adding a scenario: every scenario registers through :func:`register_scenario`
(``scenario_from_base(base)`` turns a function returning a base config into a
factory). A module of this package calls it at import and is listed in
:data:`SCENARIO_MODULES`, which this package imports after the registry is
defined; code outside the package calls ``register_scenario`` itself, after
``import coop_loc_env``::

    register_scenario("my_field", scenario_from_base(my_field_config))

A scenario with hooks::

    class Beacons(Scenario):  # its docstring's first line describes it
        obs_blocks = ("beacon_ranges",)  # registered with register_obs_block
        def base_config(self):
            return ScenarioConfig(name="beacons", n_robots=4)
        def reset_world(self, env, rng):
            env.mark_object("robot_0", 10.0, 10.0)

    register_scenario("beacons", Beacons())
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable
from typing import Any

import numpy as np

from coop_loc_env.config import ScenarioConfig

ScenarioFactory = Callable[[dict[str, Any]], ScenarioConfig]
_REGISTRY: dict[str, ScenarioFactory] = {}
_TRAINING_DEFAULTS: dict[str, dict[str, Any]] = {}


class Scenario:
    """A scenario with hooks (VMAS-style); every hook but :meth:`base_config` is optional.

    An instance is a scenario factory (called with the overrides), so
    :func:`register_scenario` takes it like a function; its docstring's first line
    describes it (:func:`describe_scenario`).
    """

    #: Registered observation blocks / reward terms this scenario adds to its config
    #: (``extra_obs_blocks`` / ``extra_reward_terms``, before those of the overrides).
    obs_blocks: tuple[str, ...] = ()
    reward_terms: tuple[str, ...] = ()

    def base_config(self) -> ScenarioConfig:
        """The scenario's config before the overrides."""
        raise NotImplementedError

    def make_config(self, overrides: dict[str, Any]) -> ScenarioConfig:
        """:meth:`base_config` with the scenario's blocks and terms, then ``overrides``."""
        base = self.base_config()
        base = dataclasses.replace(
            base,
            extra_obs_blocks=(*self.obs_blocks, *base.extra_obs_blocks),
            extra_reward_terms=(*self.reward_terms, *base.extra_reward_terms),
        )
        return base.replace(**overrides)

    def __call__(self, overrides: dict[str, Any]) -> ScenarioConfig:
        return self.make_config(overrides)

    def reset_world(self, env: Any, rng: np.random.Generator) -> None:
        """Run by ``env.reset`` once the world is placed, before the estimators start."""


#: The hooks of a scenario registered as a plain function: none.
NO_HOOKS = Scenario()


def register_scenario(name: str, factory: ScenarioFactory | Scenario | type[Scenario]) -> None:
    """Register ``factory`` under ``name``; it receives the user's overrides.

    ``factory`` is a function, a :class:`Scenario` or a :class:`Scenario` subclass
    (instantiated here).
    """
    if name in _REGISTRY:
        raise ValueError(f"scenario {name!r} is already registered")
    if isinstance(factory, type) and issubclass(factory, Scenario):
        factory = factory()
    if not callable(factory):
        raise ValueError(f"scenario {name!r} must be a function or a Scenario, got {factory!r}")
    _REGISTRY[name] = factory


def unregister_scenario(name: str) -> None:
    """Remove the scenario registered as ``name`` (``ValueError`` if there is none)."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown scenario {name!r}; known scenarios: {list_scenarios()}")
    del _REGISTRY[name]
    _TRAINING_DEFAULTS.pop(name, None)


def scenario_hooks(scenario: str) -> Scenario:
    """The :class:`Scenario` registered as ``scenario`` (:data:`NO_HOOKS` for a function)."""
    factory = _REGISTRY.get(scenario)
    return factory if isinstance(factory, Scenario) else NO_HOOKS


def scenario_from_base(base: Callable[[], ScenarioConfig]) -> ScenarioFactory:
    """A factory that builds ``base()`` and applies the overrides on top."""

    def factory(overrides: dict[str, Any]) -> ScenarioConfig:
        return base().replace(**overrides)

    factory.__doc__ = base.__doc__
    return factory


#: The training recipe both active-localization scenarios start from (``scripts/train.py``
#: option dest -> value): clone a scripted teacher (``bc_from``, set by the scenario) with
#: DAgger, then fine-tune with a cautious PPO (small steps, critic pre-fitted on the
#: clone's returns, so no reward normalization) until the wall-clock limit.
CLONE_THEN_PPO: dict[str, Any] = {
    "timesteps": 50_000_000,  # the wall-clock limit ends the run
    "bc_episodes": 16,
    "bc_epochs": 40,
    "dagger_rounds": 4,
    "dagger_epochs": 15,
    "bc_log_std": -1.5,
    "no_reward_norm": True,
    "learning_rate": 1e-4,
    "clip_range": 0.1,
    "eval_freq": 100_000,
    "checkpoint_freq": 200_000,
}


def register_training_defaults(name: str, defaults: dict[str, Any]) -> None:
    """Record ``scripts/train.py`` option defaults (option dest -> value) for scenario ``name``."""
    _TRAINING_DEFAULTS[name] = dict(defaults)


def training_defaults(name: str) -> dict[str, Any]:
    """The training option defaults a scenario carries (``{}`` when it carries none)."""
    return dict(_TRAINING_DEFAULTS.get(name, {}))


def list_scenarios() -> list[str]:
    """Names of the registered scenarios, sorted."""
    return sorted(_REGISTRY)


def describe_scenario(scenario: str) -> str:
    """One line on ``scenario``: what it sets up (the first line of its docstring)."""
    if not isinstance(scenario, str) or scenario not in _REGISTRY:
        raise ValueError(f"unknown scenario {scenario!r}; known scenarios: {list_scenarios()}")
    doc = (_REGISTRY[scenario].__doc__ or "").strip()
    return doc.splitlines()[0] if doc else scenario


def make_config(scenario: str, **overrides: Any) -> ScenarioConfig:
    """The config of ``scenario`` with ``overrides`` applied and validated."""
    if not isinstance(scenario, str) or scenario not in _REGISTRY:
        raise ValueError(f"unknown scenario {scenario!r}; known scenarios: {list_scenarios()}")
    if "name" in overrides:
        raise ValueError(f"the config key 'name' cannot be overridden (got {overrides['name']!r})")
    cfg = _REGISTRY[scenario](dict(overrides))
    cfg.validate()
    return cfg


#: The modules of this package that register the shipped scenarios (add new ones here);
#: imported here, below the registry they register into.
SCENARIO_MODULES = ("outdoor", "madhavan", "fox", "howard", "rendezvous", "active_hallway",
                    "active_lattice")
for _module in SCENARIO_MODULES:
    importlib.import_module(f"coop_loc_env.scenarios.{_module}")
