"""Hydra plugin: puts coop_loc_env's BenchMARL task YAML on hydra's search path.

With it ``python -m benchmarl.run algorithm=mappo task=coop_loc/rendezvous`` finds
``coop_loc_env/benchmarl/conf/task/coop_loc/rendezvous.yaml`` and BenchMARL's
registry knows the ``coop_loc/<scenario>`` tasks; nothing is copied into site-packages.
It does nothing where BenchMARL is not installed.
"""

from __future__ import annotations

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class CoopLocSearchPathPlugin(SearchPathPlugin):
    """Appends ``pkg://coop_loc_env.benchmarl.conf`` to BenchMARL's config search path."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        if not any("benchmarl" in str(e.path) for e in search_path.get_path()):
            return  # another hydra app: leave it alone
        try:
            import coop_loc_env.benchmarl  # noqa: F401  (registers the tasks with BenchMARL)
        except ImportError:
            return
        search_path.append(provider="coop-loc-env", path="pkg://coop_loc_env.benchmarl.conf")
