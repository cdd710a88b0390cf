"""Plugin registration, PXR_PLUGINPATH_NAME use without usdahd, and `usdahd plugin-path`."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import usdahd.usd  # registers the plugins
from usdahd import cli
from usdahd.commands import plugin_path as cmd
from usdahd.errors import SchemaError
from usdahd.usd import plugin

REPO = Path(__file__).resolve().parents[2]


def _env(**extra):
    """A clean environment for a child Python: no PYTHONPATH / PXR_PLUGINPATH_NAME inherited."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PXR_PLUGINPATH_NAME")}
    env.update(extra)
    return env


def _run(code: str, cwd: Path, **env):
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=cwd,
        env=_env(**env),
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_plugin_path_is_absolute_and_holds_the_plugins():
    p = Path(plugin.plugin_path())
    assert p.is_absolute() and p.is_dir()
    assert (p / "plugInfo.json").is_file()
    assert (p / plugin.PLUGIN_NAME / "resources" / "generatedSchema.usda").is_file()


def test_register_is_idempotent():
    from pxr import Plug

    before = len(Plug.Registry().GetAllPlugins())
    assert plugin.register() == plugin.plugin_dir()
    assert len(Plug.Registry().GetAllPlugins()) == before
    plugin.check()


def test_installed_copy_is_preferred_then_checkout(tmp_path, monkeypatch):
    pkg = tmp_path / "site" / "usdahd"
    installed = pkg / "_resources" / "plugins"
    checkout = tmp_path / "site" / "plugins"
    for d in (installed, checkout):
        (d / plugin.PLUGIN_NAME).mkdir(parents=True)
        (d / "plugInfo.json").write_text("{}")
    monkeypatch.setattr(plugin, "_PACKAGE_DIR", pkg)
    assert plugin.plugin_dir() == installed.resolve()
    (installed / "plugInfo.json").unlink()
    assert plugin.plugin_dir() == checkout.resolve()
    (checkout / "plugInfo.json").unlink()
    with pytest.raises(SchemaError, match="usdahd USD plugins are missing"):
        plugin.plugin_dir()


def test_schema_works_with_only_pxr_pluginpath_name(tmp_path):
    """usdview-style use: no usdahd import, no PYTHONPATH, only the plugin path."""
    proc = _run(
        """
        import sys
        from pxr import Usd, UsdGeom
        s = Usd.Stage.CreateInMemory()
        mesh = UsdGeom.Mesh.Define(s, "/M").GetPrim()
        xf = UsdGeom.Xform.Define(s, "/X").GetPrim()
        assert mesh.CanApplyAPI("AhdLightmapAPI") and not xf.CanApplyAPI("AhdLightmapAPI")
        assert mesh.ApplyAPI("AhdLightmapAPI")
        attr = mesh.GetAttribute("ahdLightmap:model")
        print(attr.Get(), attr.GetMetadata("allowedTokens")[0],
              mesh.GetAttribute("ahdLightmap:texture:iz").GetColorSpace())
        assert "usdahd" not in sys.modules
        """,
        cwd=tmp_path,
        PXR_PLUGINPATH_NAME=plugin.plugin_path(),
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["hhd", "ahd", "lin_rec709_scene"]


def test_relative_pxr_pluginpath_name_is_silently_ignored(tmp_path):
    """Why plugin-path prints an absolute path (usd-core 26.11 ignores relative entries)."""
    rel = os.path.relpath(plugin.plugin_path(), tmp_path)
    proc = _run(
        """
        from pxr import Usd
        print(Usd.SchemaRegistry.FindSchemaInfo("AhdLightmapAPI") is None)
        """,
        cwd=tmp_path,
        PXR_PLUGINPATH_NAME=rel,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "True"


def test_late_import_fails_loudly(tmp_path):
    """A stage created before `import usdahd.usd` freezes the schema registry: SchemaError.

    `import usdahd` alone registers nothing (it needs no pxr), so it is fine at any time."""
    proc = _run(
        """
        from pxr import Usd, UsdGeom
        UsdGeom.Mesh.Define(Usd.Stage.CreateInMemory(), "/M")
        import usdahd
        try:
            import usdahd.usd
        except Exception as exc:
            print(type(exc).__name__, exc)
        else:
            print("imported")
        """,
        cwd=tmp_path,
        PYTHONPATH=str(REPO),
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("SchemaError")
    assert "Import usdahd.usd before creating any Usd.Stage" in proc.stdout
    assert "PXR_PLUGINPATH_NAME=/" in proc.stdout


def test_cli_plugin_path_in_process(capsys, monkeypatch):
    assert cli.main(["plugin-path"]) == 0
    assert capsys.readouterr().out.strip() == plugin.plugin_path()
    monkeypatch.setenv("PXR_PLUGINPATH_NAME", f"/other/plugins{os.pathsep}{plugin.plugin_path()}")
    assert cli.main(["plugin-path", "--export"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"export PXR_PLUGINPATH_NAME={plugin.plugin_path()}{os.pathsep}/other/plugins"


def test_export_line_quotes_and_deduplicates():
    assert cmd.export_line("/a b", None) == "export PXR_PLUGINPATH_NAME='/a b'"
    assert cmd.export_line("/p", f"/p{os.pathsep}/q{os.pathsep}") == (
        f"export PXR_PLUGINPATH_NAME=/p{os.pathsep}/q"
    )


def test_cli_plugin_path_subprocess(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "usdahd", "plugin-path"],
        cwd=tmp_path,
        # The same usdahd this process imported (source checkout or installed copy).
        env=_env(PYTHONPATH=str(Path(usdahd.__file__).resolve().parents[1])),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == plugin.plugin_path()
    assert Path(proc.stdout.strip()).is_absolute()
