"""YAML config files for the scripts' ``--config FILE.yaml``.

A file is one mapping: ``scenario`` (a registered name), any
:class:`~coop_loc_env.config.ScenarioConfig` field, and ``team`` as a list of
robots (each a mapping of :class:`~coop_loc_env.config.RobotSpec` fields)::

    scenario: rendezvous
    n_robots: 4
    team:
      - {estimator: ekf}
      - {estimator: mcl, has_gps: false}

Every error is one ``ValueError`` line naming the file, the line and the key:
``team.yaml:3: key 'n_robot': unknown config key ...``.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: The key of a config file that names the scenario (every other key is a config field).
SCENARIO_KEY = "scenario"


@dataclass(frozen=True)
class ConfigFile:
    """A loaded config file: its scenario (``None`` if it names none), its config
    overrides, and the line of each key (1-based)."""

    path: Path
    scenario: str | None
    overrides: dict[str, Any]
    lines: dict[str, int]

    def where(self, key: str) -> str:
        """``FILE:LINE: key 'KEY'`` for messages."""
        return f"{self.path}:{self.lines[key]}: key {key!r}"

    def check(self, scenario: str, overrides: dict[str, Any] | None = None) -> None:
        """Build ``scenario``'s config with ``overrides`` (default: the file's); a bad value
        from the file raises ``ValueError`` naming the file, its line and the key."""
        from coop_loc_env.scenarios import list_scenarios, make_config

        overrides = dict(self.overrides if overrides is None else overrides)
        if scenario not in list_scenarios() and self.scenario == scenario:
            raise ValueError(f"{self.where(SCENARIO_KEY)}: unknown scenario {scenario!r}; "
                             f"known scenarios: {', '.join(list_scenarios())}")
        try:
            make_config(scenario, **overrides)
            return
        except ValueError as err:
            first = err
        for key in self.overrides:  # the file's first key that fails on its own
            try:
                make_config(scenario, **{key: overrides[key]})
            except ValueError as err:
                raise ValueError(f"{self.where(key)}: {err}") from None
        mentioned = [k for k in self.overrides if repr(k) in str(first) or k in str(first)]
        if mentioned:
            raise ValueError(f"{self.where(mentioned[0])}: {first}") from None
        raise first


def config_keys() -> set[str]:
    """The keys a config file may hold."""
    from coop_loc_env.config import ScenarioConfig

    return {f.name for f in dataclasses.fields(ScenarioConfig)} - {"name"} | {SCENARIO_KEY}


def load_config_file(path: str | Path) -> ConfigFile:
    """Read and check the keys of a config file (the values are checked by
    :meth:`ConfigFile.check`); raises ``ValueError`` naming the file, line and key."""
    import yaml

    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ValueError(f"{path}: no such config file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: cannot read it ({err})") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None) or getattr(err, "context_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        start = getattr(err, "context_mark", None) or mark  # where the broken node began
        key = _key_above(text, start.line if start is not None else 0)
        where = f" (in key {key!r})" if key else ""
        raise ValueError(f"{path}{line}: bad YAML{where}: {problem}") from None
    if node is None:
        return ConfigFile(path, None, {}, {})
    if not isinstance(node, yaml.MappingNode) or not isinstance(data, dict):
        raise ValueError(f"{path}:{node.start_mark.line + 1}: expected a mapping of config "
                         f"keys (scenario, n_robots, team, ...), got {type(data).__name__}")
    lines: dict[str, int] = {}
    known = config_keys()
    for key_node, _ in node.value:
        key, line = key_node.value, key_node.start_mark.line + 1
        if key in lines:
            raise ValueError(f"{path}:{line}: key {key!r}: given twice (first on line "
                             f"{lines[key]})")
        lines[key] = line
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = (f"did you mean {close[0]!r}?" if close
                    else f"known keys: {', '.join(sorted(known))}")
            raise ValueError(f"{path}:{line}: key {key!r}: unknown config key; {hint}")
    overrides = {str(k): v for k, v in data.items()}
    scenario = overrides.pop(SCENARIO_KEY, None)
    if scenario is not None and not isinstance(scenario, str):
        raise ValueError(f"{path}:{lines[SCENARIO_KEY]}: key 'scenario': expected a scenario "
                         f"name, got {scenario!r}")
    return ConfigFile(path, scenario, overrides, lines)


def _key_above(text: str, line: int) -> str | None:
    """The last top-level key at or above 0-based ``line`` of a YAML text."""
    for row in reversed(text.splitlines()[: line + 1]):
        match = re.match(r"([A-Za-z_][A-Za-z0-9_]*)\s*:", row)
        if match:
            return match.group(1)
    return None
