"""``scripts/docs_images.py``: the scenario pictures of the documentation site."""

from __future__ import annotations

from pathlib import Path

import coop_loc_env

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_renders_a_small_palette_png_per_scenario(script_module, tmp_path, capsys):
    mod = script_module("docs_images")
    assert mod.main(["--out", str(tmp_path), "--scenario", "dgps_outage", "--steps", "1"]) == 0
    path = tmp_path / "dgps_outage.png"
    assert capsys.readouterr().out.strip() == f"wrote {path}"
    from PIL import Image

    image = Image.open(path)
    assert image.mode == "P" and image.size == (600, 600)
    assert len(image.getpalette()) == 3 * 64  # the palette the docs' pictures are reduced to
    assert path.stat().st_size < 60_000


def test_the_site_has_a_picture_of_every_scenario_and_says_how_it_was_made():
    for name in coop_loc_env.list_scenarios():
        assert (DOCS / "_static" / "scenarios" / f"{name}.png").stat().st_size < 100_000
    page = (DOCS / "scenarios.md").read_text()
    assert "10 steps of zero actions, seed 0" in page
    script = (Path(__file__).resolve().parents[2] / "scripts" / "docs_images.py").read_text()
    assert 'add_argument("--steps", type=int, default=10)' in script


def test_bad_input_is_one_line_and_exit_2(script_module, tmp_path, capsys):
    mod = script_module("docs_images")
    assert mod.main(["--out", str(tmp_path), "--scenario", "nowhere"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == ["error: unknown scenario 'nowhere'"]
    assert mod.main(["--out", str(tmp_path), "--steps", "-1"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: --steps must be >= 0, got -1"]
    assert list(tmp_path.iterdir()) == []
