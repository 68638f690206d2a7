"""`nbake render` end to end: real renders at 32x32 and 4 spp, files read back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from neuralbake_client.cli.main import app
from PIL import Image
from typer.testing import CliRunner

from workers.render.render import AOV_NAMES, SCALAR_AOVS
from workers.scene.importers.image_io import read_exr, read_exr_channels

REPO = Path(__file__).resolve().parents[2]
EXAMPLE_SCENE = REPO / "assets" / "scenes" / "example.yaml"
SMALL = ["--width", "32", "--height", "32", "--spp", "4"]


def nbake(*args: str | Path):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.stderr
    return result


def render_ok(scene: str | Path, out: Path, *extra: str) -> np.ndarray:
    result = nbake("render", scene, "-o", out, *extra)
    assert result.exit_code == 0, result.stderr
    return read_exr(out)


def test_builtin_scene_renders_to_exr_and_png(tmp_path):
    out = tmp_path / "cornell.exr"
    image = render_ok("cornell_box", out, *SMALL)
    assert image.shape == (32, 32, 3)
    assert image.dtype == np.float32
    assert np.isfinite(image).all()
    assert image.mean() > 0
    with Image.open(tmp_path / "cornell.png") as png:
        assert png.size == (32, 32)
        assert png.mode == "RGB"
    assert not list(tmp_path.glob("cornell.*.exr"))  # no G-buffers unless asked


def test_yaml_scene_file_renders_and_keeps_the_camera_aspect(tmp_path):
    out = tmp_path / "nested" / "example.exr"
    image = render_ok(EXAMPLE_SCENE, out, "--width", "32", "--spp", "4")
    assert image.shape == (24, 32, 3)  # the example camera is 320x240
    assert np.isfinite(image).all()
    assert image.mean() > 0
    assert (tmp_path / "nested" / "example.png").is_file()


def test_no_png_writes_only_the_exr(tmp_path):
    render_ok("cornell_box", tmp_path / "a.exr", *SMALL, "--no-png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]


def test_aov_writes_each_gbuffer_beside_the_image(tmp_path):
    render_ok("cornell_box", tmp_path / "c.exr", *SMALL, "--aov")
    for name in AOV_NAMES:
        layers = read_exr_channels(tmp_path / f"c.{name}.exr")
        scalar = name in SCALAR_AOVS
        assert set(layers) == ({"Y"} if scalar else {"RGB"}), name
        assert layers["Y" if scalar else "RGB"].shape == ((32, 32) if scalar else (32, 32, 3)), name
        assert all(np.isfinite(v).all() for v in layers.values()), name
    depth = read_exr(tmp_path / "c.depth.exr")[..., 0]
    assert depth[8:24, 8:24].min() > 2.0  # walls and boxes lie about 3 units or more away
    normals = read_exr(tmp_path / "c.normal.exr")
    assert np.abs(normals).max() <= 1.0 + 1e-5


def test_same_seed_is_bit_identical_and_another_seed_differs(tmp_path):
    for name, seed in (("a", "7"), ("b", "7"), ("c", "8")):
        render_ok("cornell_box", tmp_path / f"{name}.exr", *SMALL, "--seed", seed, "--no-png")
    assert (tmp_path / "a.exr").read_bytes() == (tmp_path / "b.exr").read_bytes()
    assert not np.array_equal(read_exr(tmp_path / "a.exr"), read_exr(tmp_path / "c.exr"))


def test_default_output_is_out_slash_scene_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = nbake("render", "cornell_box", *SMALL)
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "out" / "cornell_box.exr").is_file()
    assert "out/cornell_box.exr" in result.stdout


def test_progress_lines_and_summary_when_not_a_terminal(tmp_path):
    result = nbake("render", "cornell_box", *SMALL, "-o", tmp_path / "p.exr")
    assert result.exit_code == 0
    assert "4/4 spp" in result.stderr
    assert "Mrays/s" in result.stdout
    assert str(tmp_path / "p.exr") in result.stdout


def test_malformed_yaml_exits_2_naming_the_file(tmp_path):
    scene = tmp_path / "broken.yaml"
    scene.write_text("materials: {white: {type: diffuse}\nobjects: [\n")
    result = nbake("render", scene, *SMALL, "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert result.stderr.startswith(f"error: {scene}: malformed YAML at line")
    assert not (tmp_path / "x.exr").exists()


def test_unknown_material_exits_2_naming_the_field(tmp_path):
    scene = tmp_path / "typo.yaml"
    scene.write_text(
        "materials: {white: {type: diffuse}}\n"
        "objects: [{name: ball, shape: {type: sphere}, material: whte}]\n"
    )
    result = nbake("render", scene, *SMALL, "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert result.stderr.startswith("error: objects[0].material: unknown material 'whte'")


def test_unknown_material_type_exits_2_naming_the_field(tmp_path):
    scene = tmp_path / "kind.yaml"
    scene.write_text(
        "materials: {white: {type: velvet}}\n"
        "objects: [{name: ball, shape: {type: sphere}, material: white}]\n"
    )
    result = nbake("render", scene, *SMALL, "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert result.stderr.startswith("error: materials.white")


def test_a_kind_material_is_drawn_by_its_kind(tmp_path):
    """`nbake render` loads the model kinds for a scene with a kind's material (and only then): the
    `mesogan` family reports the missing artifact, where no renderer would be registered without it."""
    scene = tmp_path / "fur.yaml"
    scene.write_text(
        "materials: {fur: {type: mesogan, path: no_such_artifact}}\n"
        "objects: [{name: ball, shape: {type: sphere}, material: fur}]\n"
        "environment: {type: constant, radiance: [1, 1, 1]}\n"
    )
    result = nbake("render", scene, *SMALL, "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert result.stderr.startswith("error: materials.fur.path"), result.stderr


def test_unknown_scene_name_exits_2_listing_the_builtins(tmp_path):
    result = nbake("render", "cornell_bx", "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert result.stderr.startswith("error: scene: unknown built-in scene 'cornell_bx'")
    assert "cornell_box" in result.stderr


@pytest.mark.parametrize(
    ("output", "message"),
    [("blocker/out.exr", "blocker is a file"), ("image.png", "must end in .exr"), ("dir.exr", "is a folder")],
)
def test_unusable_output_exits_2_before_rendering(tmp_path, output, message):
    (tmp_path / "blocker").write_text("")
    (tmp_path / "dir.exr").mkdir()
    result = nbake("render", "cornell_box", *SMALL, "-o", tmp_path / output)
    assert result.exit_code == 2
    assert result.stderr.startswith("error: --output: ")
    assert message in result.stderr
    assert "spp" not in result.stderr  # failed before any pass was traced


def test_out_of_range_setting_names_the_option(tmp_path):
    result = nbake("render", "cornell_box", "--spp", str(1 << 21), "-o", tmp_path / "x.exr")
    assert result.exit_code == 2
    assert result.stderr.startswith("error: --spp: ")


def test_help_describes_the_commands():
    top = nbake("--help")
    assert top.exit_code == 0
    assert "render" in top.stdout and "scenes" in top.stdout and "bake" in top.stdout
    assert "SCENE" in nbake("render", "--help").stdout  # the remote render's help points to the local one
    sub = nbake("render", "cornell_box", "--help")
    assert sub.exit_code == 0
    for option in ("--spp", "--width", "--max-depth", "--seed", "--aov", "--no-png", "--json"):
        assert option in sub.stdout


def test_installed_console_script_prints_json_lines(tmp_path):
    """The real `nbake` entry point in a subprocess: one progress object per pass, then the result."""
    exe = Path(sys.executable).with_name("nbake")
    out = tmp_path / "j.exr"
    proc = subprocess.run(
        [exe, "render", "cornell_box", *SMALL, "--aov", "--json", "-o", out],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    events = [json.loads(line) for line in proc.stdout.splitlines()]
    assert {e["event"] for e in events[:-1]} == {"progress"}
    assert events[-2]["samples_done"] == events[-2]["samples_total"] == 4
    done = events[-1]
    assert done["event"] == "done"
    assert (done["width"], done["height"], done["spp"]) == (32, 32, 4)
    assert done["mrays_per_second"] > 0
    assert Path(done["image"]) == out and out.is_file()
    assert Path(done["preview"]).is_file()
    assert set(done["aovs"]) == set(AOV_NAMES)
    assert all(Path(p).is_file() for p in done["aovs"].values())


@pytest.mark.parametrize("scene", ["cornell_box", EXAMPLE_SCENE], ids=["cornell_box", "example"])
def test_thread_count_changes_no_bit_of_the_image(tmp_path, scene):
    """Work items are seeded by (seed, pass, tile) and summed in a fixed order (workers/render/render.py):
    96 pixels wide makes several 64-pixel tiles for two threads to share."""
    for threads in ("1", "2"):
        render_ok(scene, tmp_path / f"t{threads}.exr", "--width", "96", "--spp", "4", "--threads", threads)
    assert (tmp_path / "t1.exr").read_bytes() == (tmp_path / "t2.exr").read_bytes()
    assert (tmp_path / "t1.png").read_bytes() == (tmp_path / "t2.png").read_bytes()
