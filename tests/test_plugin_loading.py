"""A plug-in that cannot be loaded (named in ``BTRUN_PLUGINS`` or installed) is refused
with one line that says which, where it was named and why, never a traceback, and nothing
runs (exit 2)."""

from __future__ import annotations

import pytest

from bt_engine import plugins
from bt_engine.cli import main


@pytest.fixture
def plugin_env(tmp_path, monkeypatch):
    """Set ``BTRUN_PLUGINS`` to a module written in ``tmp_path`` (fresh plug-in list)."""

    def use(spec: str, source: str | None = None) -> None:
        if source is not None:
            (tmp_path / f"{spec.partition(':')[0]}.py").write_text(source)
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.setenv("BTRUN_PLUGINS", spec)
        monkeypatch.setattr(plugins, "_loaded", None)

    yield use
    plugins._loaded = None  # the next test loads the installed plug-ins again


@pytest.mark.parametrize(
    "spec, source, expected",
    [
        (
            "no_such_plugin_mod:PLUGIN",
            None,
            "btrun: plug-in 'no_such_plugin_mod:PLUGIN' (BTRUN_PLUGINS) could not be loaded: "
            "ModuleNotFoundError: No module named 'no_such_plugin_mod'",
        ),
        (
            "half_plugin:PLUGIN",
            "class P:\n    name = 'half'\n\nPLUGIN = P()\n",
            "btrun: plug-in 'half_plugin:PLUGIN' (BTRUN_PLUGINS) is not a plug-in object: it "
            "lacks load_target, write_report, commands",
        ),
        (
            "typo_plugin:PLUGN",
            "PLUGIN = None\n",
            "could not be loaded: AttributeError: module 'typo_plugin' has no attribute 'PLUGN'",
        ),
        (
            "raising_plugin",
            "import os\n\nraise RuntimeError('no licence file')\n",
            "could not be loaded: RuntimeError: no licence file (",
        ),
    ],
)
def test_a_plugin_that_cannot_load_is_one_line_and_exit_2(
    plugin_env, tmp_path, capsys, spec, source, expected
):
    plugin_env(spec, source)
    assert main(["missions/square.xml", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()
    if spec == "raising_plugin":  # where in the plug-in's own code it failed
        assert f"{tmp_path / 'raising_plugin.py'}:3)" in err
