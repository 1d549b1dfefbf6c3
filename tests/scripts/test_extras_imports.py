"""Each training path imports only its own extra: the RLlib path runs without stable-baselines3."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# stable_baselines3 made unimportable (as in a venv with only the rllib extra), then
# train.py's RLlib path up to the point where it would start Ray
BLOCKED_SB3 = """
import sys
sys.modules["stable_baselines3"] = None
sys.path.insert(0, "scripts")
import train
args = train.parse_args(["--backend", "rllib", "--scenario", "rendezvous", "--out", "x"])
cfg = train.config_from_args(args)
cfg.validate()
from policies.learning.rllib_backend import run_from_train_config
run = run_from_train_config(cfg, None, None)
import policies.learning.vec_env
print("ok", type(run).__name__, "stable_baselines3" in sys.modules and
      sys.modules["stable_baselines3"] is not None)
"""


def test_train_rllib_path_needs_no_stable_baselines3():
    out = subprocess.run([sys.executable, "-c", BLOCKED_SB3], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["ok", "RLlibRun", "False"]


def test_the_sb3_vec_env_is_still_reachable_from_policies_vec_env():
    from policies.learning import sb3_vec_env, vec_env

    assert vec_env.ParallelEnvVecEnv is sb3_vec_env.ParallelEnvVecEnv
