"""Named scenarios: registry, lookup and keyword overrides.

A scenario is a function returning a :class:`~coop_loc_env.config.ScenarioConfig`
from a dict of overrides. :func:`make_config` looks one up by name and applies
the overrides (unknown keys and invalid values raise ``ValueError``).

Adding a scenario: every scenario registers through :func:`register_scenario`
(``scenario_from_base(base)`` turns a function returning a base config into a
factory). A module of this package calls it at import and is listed in
:data:`SCENARIO_MODULES`, which this package imports after the registry is
defined; code outside the package calls ``register_scenario`` itself, after
``import coop_loc_env``::

    register_scenario("my_field", scenario_from_base(my_field_config))
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from coop_loc_env.config import ScenarioConfig

ScenarioFactory = Callable[[dict[str, Any]], ScenarioConfig]
_REGISTRY: dict[str, ScenarioFactory] = {}
_TRAINING_DEFAULTS: dict[str, dict[str, Any]] = {}


def register_scenario(name: str, factory: ScenarioFactory) -> None:
    """Register ``factory`` under ``name``; it receives the user's overrides."""
    if name in _REGISTRY:
        raise ValueError(f"scenario {name!r} is already registered")
    _REGISTRY[name] = factory


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
SCENARIO_MODULES = ("outdoor", "madhavan", "fox", "howard", "rendezvous", "active_hallway")
for _module in SCENARIO_MODULES:
    importlib.import_module(f"coop_loc_env.scenarios.{_module}")
