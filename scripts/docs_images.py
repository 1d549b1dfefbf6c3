"""Render one frame per registered scenario for the documentation site.

    python scripts/docs_images.py --out outputs/scenarios

Each scenario runs ``--steps`` steps of zero actions (robots standing still, so the frame
shows the start of an episode with the beliefs after a few readings) from seed 0 and is
saved as ``OUT/<scenario>.png``, reduced to a palette of 64 colours to keep the files
small. The site's pictures (``docs/_static/scenarios/``) are made with
``--out docs/_static/scenarios``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import coop_loc_env


def render_frame(scenario: str, steps: int = 10, seed: int = 0) -> np.ndarray:
    """The ``(H, W, 3)`` frame of ``scenario`` after ``steps`` steps of zero actions."""
    env = coop_loc_env.parallel_env(scenario, render_mode="rgb_array")
    env.reset(seed=seed)
    for _ in range(steps):
        if not env.agents:
            break
        env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
    frame = env.render()
    env.close()
    return frame


def save_small_png(frame: np.ndarray, path: Path, colors: int = 64) -> None:
    """Save ``frame`` as a palette PNG of at most ``colors`` colours."""
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    image = Image.fromarray(frame[..., :3]).quantize(colors=colors)
    image.save(path, optimize=True)


def main(argv: list[str] | None = None) -> int:
    """Render every scenario (or those named by ``--scenario``); returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("outputs/scenarios"))
    parser.add_argument("--scenario", action="append", default=None,
                        help="a scenario to render (repeatable; default: all registered)")
    parser.add_argument("--steps", type=int, default=10)
    args = parser.parse_args(argv)
    names = args.scenario or coop_loc_env.list_scenarios()
    unknown = sorted(set(names) - set(coop_loc_env.list_scenarios()))
    if unknown:
        print(f"error: unknown scenario {unknown[0]!r}", file=sys.stderr)
        return 2
    if args.steps < 0:
        print(f"error: --steps must be >= 0, got {args.steps}", file=sys.stderr)
        return 2
    for name in names:
        path = args.out / f"{name}.png"
        save_small_png(render_frame(name, args.steps), path)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
