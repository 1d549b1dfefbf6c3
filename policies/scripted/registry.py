"""The registry of scripted policy names: ``NAME`` or ``NAME:ARG`` -> a policy object.

:func:`policy_names` lists them (``fsm``, ``random``, ``seek``, ``still``,
``wander``, ``gather``, ``infogain``, ``corridor``, ``hypothesis``, ``split``);
:func:`register_policy` adds one. :func:`policies.learning.loader.make_policy`
resolves a spec against this registry first, then as the path of a saved model;
``scripts/evaluate.py``, ``--compare`` and ``scripts/train.py`` all go through it.
"""

from __future__ import annotations

from collections.abc import Callable

from policies.scripted.baselines import Policy, RandomPolicy, SeekTeammatePolicy, StandStillPolicy
from policies.scripted.fsm import FSMPolicy

PolicyFactory = Callable[[str], Policy]
"""Builds a policy from the argument after ``NAME:`` in a spec (``""`` when there is none)."""
_POLICIES: dict[str, tuple[PolicyFactory, str]] = {}


def register_policy(name: str, factory: PolicyFactory, description: str) -> None:
    """Register ``factory`` as policy ``name`` for :func:`~policies.learning.loader.make_policy`
    (and ``evaluate.py``)."""
    if name in _POLICIES or ":" in name:
        raise ValueError(f"policy name {name!r} is taken or contains ':'")
    _POLICIES[name] = (factory, description)


def policy_names() -> list[str]:
    """The registered policy names, in registration order."""
    return list(_POLICIES)


def policy_help() -> str:
    """One line per registered policy: ``NAME  description``."""
    width = max(len(n) for n in _POLICIES)
    return "\n".join(f"  {n:<{width}}  {d}" for n, (_, d) in _POLICIES.items())


def registered_policy(spec: str) -> Policy | None:
    """The policy of a registered ``NAME`` or ``NAME:ARG``; ``None`` when ``NAME`` is not one."""
    name, _, arg = str(spec).partition(":")
    if name in _POLICIES:
        return _POLICIES[name][0](arg)
    return None


def _no_argument(cls: Callable[[], Policy], name: str) -> PolicyFactory:
    def factory(arg: str) -> Policy:
        if arg:
            raise ValueError(f"policy {name!r} takes no argument, got {name}:{arg}")
        return cls()

    return factory


def _with_speed(cls: Callable[..., Policy], name: str, arg: str) -> Policy:
    """``cls()``, or ``cls(float(arg))`` for a spec ``NAME:SPEED``."""
    if not arg:
        return cls()
    try:
        return cls(float(arg))
    except ValueError as err:
        raise ValueError(f"policy '{name}:{arg}': {name}:SPEED needs a speed in (0, 1]") from err


def _wander(arg: str) -> Policy:
    from policies.scripted.wander import WanderPolicy

    return _with_speed(WanderPolicy, "wander", arg)


register_policy("fsm", _no_argument(FSMPolicy, "fsm"),
                "terrain-traversal state machine (Madhavan et al.)")
register_policy("random", _no_argument(RandomPolicy, "random"), "uniform random actions")
register_policy("seek", _no_argument(SeekTeammatePolicy, "seek"),
                "drive toward a teammate when uncertain")
register_policy("still", _no_argument(StandStillPolicy, "still"), "every robot stands still")
register_policy("wander", _wander, "Fox et al.'s wander behaviour; wander:SPEED sets the speed")


def _gather(arg: str) -> Policy:
    from policies.scripted.gather import GatherPolicy

    return _no_argument(GatherPolicy, "gather")(arg)


def _infogain(arg: str) -> Policy:
    from policies.scripted.infogain import InfoGainPolicy

    return _no_argument(InfoGainPolicy, "infogain")(arg)


def _corridor(arg: str) -> Policy:
    from policies.scripted.corridor import CorridorPolicy

    return _with_speed(CorridorPolicy, "corridor", arg)


def _hypothesis(arg: str) -> Policy:
    from policies.scripted.hypothesis import SELECT_MODES, HypothesisPolicy

    if arg and arg not in SELECT_MODES:
        raise ValueError(f"policy 'hypothesis:{arg}': the argument must be one of "
                         f"{SELECT_MODES} (how targets are chosen)")
    # the greedy variant also weighs the symmetric copies the filter keeps of its main mode
    return HypothesisPolicy(select=arg, copies=arg == "nearest") if arg else HypothesisPolicy()


def _split(arg: str) -> Policy:
    from policies.scripted.split import SplitPolicy

    return _no_argument(SplitPolicy, "split")(arg)


register_policy("gather", _gather,
                "drive toward the teammates that can inform you (by the shared estimates)")
register_policy("infogain", _infogain,
                "greedy information seeking over motion primitives: least expected log det "
                "(EKF beliefs) or posterior entropy (MCL particle beliefs)")
register_policy("corridor", _corridor,
                "follow the free space ahead at full speed by the own scan; corridor:SPEED")
register_policy("hypothesis", _hypothesis,
                "hypothesis elimination with far targets: drive where the belief's modes "
                "predict different readings (MCL), localized robots meet the lost ones; "
                "hypothesis:nearest drives to the nearest such place (greedy), counting the "
                "map's symmetric copies of the main mode")
register_policy("split", _split,
                "team hypothesis testing: lost robots split over different places that tell "
                "their modes apart (nearest first), localized robots meet the lost ones")
POLICY_NAMES = tuple(_POLICIES)  # the built-in names
