"""Rig settings are declared once: the schema comes from the dataclasses, the docs from the
schema, and a rig file need only state what differs."""

from __future__ import annotations

import dataclasses
import os

from bt_engine.cli import main
from drivers.rig.loader import load_rig
from drivers.rig.schema import RIG_SCHEMA, settings_markdown
from drivers.safety.policies import DEFAULT_POLICIES, SafetyConfig
from drivers.settings import defaults
from drivers.vehicle.config import VehicleConfig

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_docs_rig_settings_is_generated_from_the_schema() -> None:
    with open(os.path.join(REPO, "docs", "rig-settings.md"), encoding="utf-8") as f:
        assert f.read() == settings_markdown(), (
            "docs/rig-settings.md is out of date: btrun rig settings --markdown > "
            "docs/rig-settings.md"
        )


def test_control_and_safety_defaults_come_from_their_dataclasses() -> None:
    d = defaults(RIG_SCHEMA)
    cfg = VehicleConfig()
    for f in dataclasses.fields(VehicleConfig):
        if "setting" in f.metadata:
            assert d["control"][f.name] == getattr(cfg, f.name), f.name
    assert VehicleConfig.from_dict(d["control"]) == cfg
    safety = SafetyConfig()
    assert d["safety"]["geofence"]["max_m"] == list(safety.geofence_max_m)
    assert d["safety"]["battery_low_v"] == safety.battery_low_v
    for name, pol in DEFAULT_POLICIES.items():
        assert d["safety"]["policies"][name] == {
            "action": pol.action,
            "grace_s": pol.grace_s,
            "hold_s": pol.hold_s,
        }
    assert SafetyConfig.from_dict(d["safety"]) == safety


def test_a_changed_default_reaches_schema_and_config(monkeypatch) -> None:
    """One declaration: the rig file does not repeat defaults, so a rig loaded without a
    control section gets exactly the dataclass's values."""
    rig = load_rig(os.path.join(REPO, "rigs", "sim.yaml"), {"control.rate_hz": "50"})
    cfg = VehicleConfig.from_dict(rig.data["control"])
    assert cfg.rate_hz == 50.0 and cfg.velocity_kp == VehicleConfig().velocity_kp


def test_btrun_rig_settings_and_check(capsys, tmp_path) -> None:
    assert main(["rig", "settings"]) == 0
    out = capsys.readouterr().out
    assert "control.velocity_kp (float, default 2.5)" in out
    assert "safety.geofence.margin_m" in out
    assert main(["rig", "check", os.path.join(REPO, "rigs", "sitl.yaml")]) == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("link: sim\ncontrol:\n  rate_hz: fast\n")
    assert main(["rig", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:3:12: control.rate_hz: expected a number" in err and "Traceback" not in err


def test_a_key_that_is_not_a_plain_name_is_a_located_problem(tmp_path, capsys) -> None:
    bad = tmp_path / "listkey.yaml"
    bad.write_text("control:\n  ? [a, b]\n  : 3\n")
    assert main(["rig", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:2:5: a key must be a plain name" in err and "Traceback" not in err
