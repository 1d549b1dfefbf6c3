"""What the command-line scripts share: one-line errors, the extra each optional package
comes with, ``--set KEY=VALUE`` values, and ``--config FILE.yaml`` files.

Every script's ``__main__`` is ``sys.exit(run_script(main))``: bad arguments and a
missing optional package each give one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

#: The extra of this project that installs each optional top-level module
#: (``pip install -e ".[EXTRA]"``): the one whose docs name the feature that needs it.
EXTRA_OF: dict[str, str] = {
    "tqdm": "render",
    "matplotlib": "render",
    "imageio": "render",
    "stable_baselines3": "train",
    "torch": "train",
    "tensorboard": "train",
    "rich": "train",
    "ray": "rllib",
    "torchrl": "torchrl",
    "tensordict": "torchrl",
    "benchmarl": "benchmarl",
    "hydra": "benchmarl",
    "omegaconf": "benchmarl",
    "gtsam": "check",
    "mpe2": "bench",
}


def missing_extra_line(module: str, extra: str | None = None) -> str:
    """The one line telling which extra installs ``module`` (a top-level module name):
    ``extra``, else the one :data:`EXTRA_OF` names."""
    extra = extra or EXTRA_OF[module]
    return (f"error: this needs {module}, which is not installed: "
            f'pip install -e ".[{extra}]"')


def missing_module(err: BaseException) -> str | None:
    """The optional top-level module whose absence raised ``err``, or ``None``."""
    if not isinstance(err, ModuleNotFoundError) or not err.name:
        return None
    root = err.name.split(".")[0]
    return root if root in EXTRA_OF else None


def run_script(main: Callable[..., Any], argv: list[str] | None = None) -> Any:
    """Run a script's ``main`` (``main()``, or ``main(argv)`` when given); a missing optional
    package gives one line and status 2."""
    try:
        return main() if argv is None else main(argv)
    except ModuleNotFoundError as err:
        module = missing_module(err)
        if module is None:
            raise
        print(missing_extra_line(module, getattr(err, "extra", None)), file=sys.stderr)
        return 2


def require(*modules: str, extra: str | None = None) -> None:
    """Import ``modules`` now, so that a missing optional package stops a script before its
    work rather than after it (:func:`run_script` turns that into one line naming ``extra``,
    by default the module's in :data:`EXTRA_OF`)."""
    import importlib

    for module in modules:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as err:
            err.extra = extra
            raise


class ScriptParser(argparse.ArgumentParser):
    """``argparse`` with a one-line error (``PROG: error: MESSAGE (see --help)``), status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def parse_value(raw: str) -> Any:
    """A ``--set`` value: a Python literal (``4``, ``None``, ``[1, 2]``), else YAML
    (``[{estimator: ekf}]``, ``true``), else the string itself."""
    try:
        return ast.literal_eval(raw)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        pass
    import yaml

    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw
    if isinstance(value, bool) and raw.strip().lower() not in ("true", "false"):
        return raw  # YAML 1.1 reads yes/no/on/off as booleans: keep such words as words
    return raw if value is None else value


def parse_overrides(pairs: list[str] | None) -> dict[str, Any]:
    """``["KEY=VALUE", ...]`` to a dict, each value read by :func:`parse_value`."""
    out: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, raw = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"--set expects KEY=VALUE, got {pair!r}")
        out[key] = parse_value(raw)
    return out


def add_config_arguments(p: argparse.ArgumentParser, scenario_default: str) -> None:
    """``--scenario``, ``--config FILE.yaml`` and ``--set KEY=VALUE`` (resolved by
    :func:`scenario_and_overrides`)."""
    p.add_argument("--scenario", default=None,
                   help=f"registered scenario name (default: the config file's, else "
                        f"{scenario_default})")
    p.add_argument("--config", type=Path, default=None, metavar="FILE.yaml",
                   help="YAML config: scenario, any scenario config key, team (a list of "
                        "robots); --set and the options given apply on top")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override, repeatable; VALUE is a Python literal or YAML "
                        "(e.g. --set n_robots=4 --set 'team=[{estimator: ekf}]')")
    p.set_defaults(scenario_default=scenario_default)


def scenario_and_overrides(args: argparse.Namespace) -> tuple[str, dict[str, Any]]:
    """The scenario and config overrides of ``args`` (from :func:`add_config_arguments`):
    the config file's, then ``--set`` on top; ``--scenario`` beats the file's scenario.
    Raises ``ValueError`` (naming the file, the key and its line) on a bad file."""
    from coop_loc_env.config_file import load_config_file

    scenario, overrides = None, {}
    if args.config is not None:
        loaded = load_config_file(args.config)
        scenario, overrides = loaded.scenario, dict(loaded.overrides)
    overrides.update(parse_overrides(args.overrides))
    if args.scenario is not None:
        scenario = args.scenario
    if scenario is None:
        scenario = args.scenario_default
    if args.config is not None:
        loaded.check(scenario, overrides)
    return scenario, overrides
