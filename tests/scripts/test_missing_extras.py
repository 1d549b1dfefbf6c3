"""Each script, run with an optional package made unimportable (as in a venv without its
extra), stops with one line on stderr naming the extra to install, and exit status 2
(``.ci/extras_matrix.sh`` checks the same in real venvs, one per extra)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from coop_loc_env.cli import EXTRA_OF, missing_module, require, run_script

ROOT = Path(__file__).resolve().parents[2]

# (script, arguments, the module made unimportable, the extra the line must name); the
# arguments are each script's documented use, cut short ({tmp}: a scratch folder)
CASES = [
    ("evaluate.py", ["--policy", "fsm", "--episodes", "1", "--max-cycles", "5"], "tqdm",
     "render"),
    ("evaluate.py", ["--episodes", "1", "--max-cycles", "5", "--no-progress", "--plot-dir",
                     "{tmp}"], "matplotlib", "render"),
    ("evaluate.py", ["--compare", "fsm,random", "--episodes", "1", "--max-cycles", "5",
                     "--no-progress"], "matplotlib", "render"),
    ("evaluate.py", ["--policy", "{tmp}/model.zip", "--episodes", "1", "--no-progress"],
     "stable_baselines3", "train"),
    ("evaluate.py", ["--policy", "{tmp}/rllib_run", "--episodes", "1", "--no-progress"],
     "ray", "rllib"),
    ("train.py", ["--out", "{tmp}/run", "--timesteps", "100"], "stable_baselines3", "train"),
    ("train.py", ["--backend", "rllib", "--out", "{tmp}/run", "--timesteps", "100"], "ray",
     "rllib"),
    ("run_episode.py", ["--steps", "3", "--frame", "{tmp}/frame.png"], "imageio", "render"),
    ("run_episode.py", ["--steps", "3", "--frame", "{tmp}/frame.png"], "matplotlib", "render"),
    ("render_episode.py", ["--max-cycles", "3", "--out", "{tmp}/e.gif"], "imageio", "render"),
    ("render_episode.py", ["--max-cycles", "3", "--out", "{tmp}/e.gif"], "tqdm", "render"),
    ("plot_training.py", ["--run", "{tmp}/run", "--out", "{tmp}/t.png"], "matplotlib",
     "render"),
    ("plot_trajectories.py", ["--policies", "gather", "--out", "{tmp}/p.png"], "matplotlib",
     "render"),
    ("reproduce_fox.py", ["--experiment", "hallway", "--seeds", "1", "--duration", "3"],
     "matplotlib", "render"),
    ("reproduce_fox.py", ["--experiment", "hallway", "--plot-dir", ""], "tqdm", "render"),
    ("reproduce_howard.py", ["--dispersal-duration", "1"], "matplotlib", "render"),
    ("reproduce_madhavan.py", [], "matplotlib", "render"),
    ("replay_logs.py", ["tests/data/mrclam_excerpt", "--plot", "{tmp}/r.png"], "matplotlib",
     "render"),
    ("replay_logs.py", ["tests/data/mrclam_excerpt"], "tqdm", "render"),
    ("bench/torchrl_step.py", ["--steps", "5", "--reps", "1"], "torchrl", "torchrl"),
    ("bench/torchrl_step.py", ["--steps", "5", "--reps", "1"], "tensordict", "torchrl"),
    ("bench/benchmarl_mappo.py", ["--minutes", "0.01", "--episodes", "2"], "benchmarl",
     "benchmarl"),
    # torch last: it cannot be imported again once dropped from sys.modules
    ("bench/inference.py", [], "torch", "train"),
    ("bench/torchrl_step.py", ["--steps", "5", "--reps", "1"], "torch", "torchrl"),
    ("train.py", ["--out", "{tmp}/run", "--timesteps", "100"], "torch", "train"),
]

# Runs every case in one interpreter (one import of everything, not one per case): blocks
# the case's module (dropping it and its submodules, which earlier cases may have imported)
# in sys.modules, runs the script as __main__ and records its exit status and stderr; an
# uncaught exception is recorded as a traceback.
RUNNER = r"""
import contextlib, io, json, runpy, sys, traceback
cases, results = json.loads(sys.argv[1]), []
for script, args, module in cases:
    for name in [m for m in sys.modules if m == module or m.startswith(module + ".")]:
        del sys.modules[name]
    sys.modules[module] = None
    sys.argv = [script, *args]
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            runpy.run_path(script, run_name="__main__")
            rc = 0
        except SystemExit as stop:
            rc = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
        except BaseException:
            rc, _ = "traceback", traceback.print_exc(file=err)
    results.append([rc, err.getvalue()])
    del sys.modules[module]
print(json.dumps(results))
"""


def test_every_script_names_the_extra_of_a_missing_package(tmp_path):
    (tmp_path / "model.zip").write_bytes(b"not read: the import comes first")
    (tmp_path / "rllib_run" / "checkpoint").mkdir(parents=True)
    (tmp_path / "rllib_run" / "checkpoint" / "rllib_checkpoint.json").write_text("{}")
    (tmp_path / "run").mkdir()
    cases = [[f"scripts/{script}", [a.format(tmp=tmp_path) for a in args], module]
             for script, args, module, _ in CASES]
    env = {**os.environ, "PYTHONHASHSEED": "0"}  # train.py --backend rllib would re-exec
    out = subprocess.run([sys.executable, "-c", RUNNER, json.dumps(cases)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    results = json.loads(out.stdout.strip().splitlines()[-1])
    wrong = []
    for (script, args, module, extra), (rc, err) in zip(CASES, results, strict=True):
        lines = [line for line in err.splitlines() if line.strip()]
        if rc != 2 or len(lines) != 1 or f'pip install -e ".[{extra}]"' not in lines[0]:
            wrong.append(f"{script} {' '.join(args)} without {module}: rc {rc}, {err[-600:]}")
    assert not wrong, "\n".join(wrong)


def test_every_extra_named_exists_in_pyproject():
    text = (ROOT / "pyproject.toml").read_text()
    for extra in set(EXTRA_OF.values()):
        assert f"\n{extra} = [" in text, extra


def test_run_script_lets_other_missing_modules_and_errors_through():
    def needs(name):
        def main():
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return main

    assert run_script(needs("matplotlib.pyplot")) == 2  # a submodule of an optional one
    with pytest.raises(ModuleNotFoundError):
        run_script(needs("no_such_module_here"))  # not optional: a real bug, left loud
    assert missing_module(ImportError("x")) is None
    with pytest.raises(ModuleNotFoundError) as err:
        require("no_such_module_here", extra="render")
    assert err.value.extra == "render"


def test_the_line_names_the_pip_command(capsys):
    def main():
        require("no_such_module_here")

    EXTRA_OF["no_such_module_here"] = "rllib"
    try:
        assert run_script(main) == 2
    finally:
        del EXTRA_OF["no_such_module_here"]
    assert capsys.readouterr().err == (
        'error: this needs no_such_module_here, which is not installed: '
        'pip install -e ".[rllib]"\n')
