"""Where a bake writes and what it trusts (issues 13 and 18): texture names unique per output
layer and content-addressed, so two scenario layers share a folder; files of a layer no layer
references are removed, other layers' files never; a previous layer's paths outside the output
folder are never followed."""

from __future__ import annotations

import shutil
from pathlib import Path

from tests.scenes import baked_mean_iz
from usdahd import cli, pipeline
from usdahd.usd.author import referenced_assets

ROOT = Path(__file__).resolve().parents[2]
PLANE = ROOT / "samples" / "open_plane.usda"
FAST = ["--resolution", "8", "--samples", "16", "--bounces", "0", "--quiet"]


def _run(capsys, *argv) -> int:
    code = cli.main(list(argv))
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    return code


def _scenario(tmp_path: Path, name: str, intensity: float) -> Path:
    text = PLANE.read_text(encoding="utf-8")
    old = "float inputs:intensity = 1\n"
    assert text.count(old) == 1
    path = tmp_path / f"{name}.usda"
    path.write_text(text.replace(old, f"float inputs:intensity = {intensity}\n"), "utf-8")
    return path


_iz = baked_mean_iz


def test_day_and_night_layers_in_one_folder_keep_their_own_lighting(tmp_path, capsys):
    day, night = _scenario(tmp_path, "day", 1.0), _scenario(tmp_path, "night", 0.25)
    day_layer, night_layer = tmp_path / "day.lightmaps.usda", tmp_path / "night.lightmaps.usda"
    assert _run(capsys, "bake", str(day), *FAST) == 0
    assert _run(capsys, "bake", str(night), *FAST) == 0
    # The open plane sees only the uniform sky: I_z = intensity exactly (docs: samples/README).
    assert abs(_iz(day_layer) - 1.0) < 0.02
    assert abs(_iz(night_layer) - 0.25) < 0.005
    day_files = referenced_assets(day_layer)
    night_files = referenced_assets(night_layer)
    assert day_files and night_files and not day_files & night_files
    night_bytes = {f: f.read_bytes() for f in night_files}
    # Re-baking day (new resolution: new files, day's old ones cleaned up) leaves night alone.
    assert _run(capsys, "bake", str(day), *FAST[:1], "12", *FAST[2:]) == 0
    assert {f: f.read_bytes() for f in night_files} == night_bytes
    assert _run(capsys, "validate", "--quiet", str(night_layer)) == 0
    assert _run(capsys, "validate", "--quiet", str(day_layer)) == 0
    assert abs(_iz(night_layer) - 0.25) < 0.005
    left = {f.resolve() for f in (tmp_path / "lightmaps").iterdir()}
    assert left == referenced_assets(day_layer) | night_files  # day's old files removed


def test_texture_names_are_content_addressed_and_per_layer(tmp_path, capsys):
    stage = _scenario(tmp_path, "a", 1.0)
    assert _run(capsys, "bake", str(stage), *FAST) == 0
    layer = tmp_path / "a.lightmaps.usda"
    prefix = pipeline.layer_prefix(layer)
    import hashlib

    for f in referenced_assets(layer):
        assert f.name.startswith(prefix + ".")
        digest = f.name.split(".")[-2]
        assert hashlib.sha256(f.read_bytes()).hexdigest().startswith(digest)
    assert pipeline.layer_prefix(tmp_path / "a.b.usda") != pipeline.layer_prefix(
        tmp_path / "a_b.usda"
    )


def test_previous_layer_paths_outside_the_output_folder_are_not_trusted(tmp_path, capsys):
    stage = tmp_path / "scene" / "plane.usda"
    stage.parent.mkdir()
    shutil.copy2(PLANE, stage)
    assert _run(capsys, "bake", str(stage), *FAST) == 0
    layer = stage.parent / "plane.lightmaps.usda"
    outside = tmp_path / "x"
    outside.mkdir()
    # Hand-edit: move one texture outside and point the layer at it (hash unchanged).
    text = layer.read_text()
    ref = sorted(f for f in referenced_assets(layer) if ".iz." in f.name)[0]
    moved = outside / ref.name
    shutil.copy2(ref, moved)
    layer.write_text(text.replace(f"./lightmaps/{ref.name}", f"../x/{ref.name}"))
    before = moved.read_bytes()
    code = cli.main(["bake", str(stage), *FAST[:-1], "--json"])
    out = capsys.readouterr().out
    assert code == 0
    import json

    report = json.loads(out)
    assert report["prims"][0]["status"] == "baked"  # not skipped on the old record's word
    assert any("outside" in w and "re-baked" in w for w in report["warnings"])
    for f in referenced_assets(layer):
        assert f.parent == (stage.parent / "lightmaps").resolve()
    assert moved.read_bytes() == before  # never written, never removed
    assert _run(capsys, "validate", "--quiet", str(layer)) == 0


def test_textures_of_an_older_usdahd_are_removed_unless_another_layer_uses_them(tmp_path, capsys):
    """Older bakes named textures ``<prim stem>.<role>.<ext>`` (shared by every layer of the
    folder). After a re-bake, those the previous layer referenced go, except ones another
    usdahd layer in the folder still references."""
    stage = _scenario(tmp_path, "a", 1.0)
    assert _run(capsys, "bake", str(stage), *FAST) == 0
    layer = tmp_path / "a.lightmaps.usda"
    text = layer.read_text()
    legacy = []
    for f in sorted(referenced_assets(layer)):
        _, stem, role, _, ext = f.name.split(".")
        old = f.with_name(f"{stem}.{role}.{ext}")
        f.rename(old)
        text = text.replace(f"./lightmaps/{f.name}", f"./lightmaps/{old.name}")
        legacy.append(old)
    layer.write_text(text)
    assert _run(capsys, "validate", "--quiet", str(layer)) == 0  # a valid old-style bake
    shared = legacy[0]
    other = tmp_path / "other.lightmaps.usda"
    other.write_text(
        '#usda 1.0\n(\n    doc = "baked by usdahd (test)"\n)\n\n'
        f'over "X"\n{{\n    asset tex = @./lightmaps/{shared.name}@\n}}\n'
    )
    assert _run(capsys, "bake", str(stage), *FAST, "--force", "--seed", "3") == 0
    assert shared.is_file()
    assert not any(f.exists() for f in legacy[1:])
    assert _run(capsys, "validate", "--quiet", str(layer)) == 0
