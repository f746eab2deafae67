"""White balance: calibration from a white target, factors applied, rig file edited in place."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

from perception.synth.render import SensorModel, illuminant_bgr
from perception.white_balance import (
    apply_white_balance,
    calibrate,
    decode_raw,
    main,
    preprocess,
    render_white_target,
    write_rig_factors,
)


def test_calibration_recovers_known_channel_gains():
    gains = np.array([0.62, 1.0, 0.81])  # B, G, R of a greenish sensor
    rng = np.random.default_rng(0)
    white = np.clip(230 * gains + rng.normal(0, 0.3, (244, 324, 3)), 0, 255).astype(np.uint8)
    f = np.array(calibrate(white))
    assert np.allclose(f / f[1], 1.0 / gains, rtol=0.02)
    balanced = apply_white_balance(white, tuple(f))
    assert np.allclose(balanced.reshape(-1, 3).mean(axis=0), 253, atol=3)


def test_calibration_through_the_simulated_camera():
    raw = render_white_target(np.random.default_rng(0), colour_temperature_k=4000)
    f = np.array(calibrate(raw))
    true = np.asarray(SensorModel().channel_gain_bgr) * np.asarray(illuminant_bgr(4000))
    assert np.allclose(f / f[1], true[1] / true, rtol=0.04)
    b, g, r = preprocess(raw, tuple(f)).reshape(-1, 3).astype(float).mean(axis=0)
    assert abs(b - g) < 0.04 * g and abs(r - g) < 0.04 * g  # white is neutral again


def test_study_method_is_listing_5():
    img = np.zeros((100, 100, 3), np.uint8)
    img[:50] = (100, 200, 150)  # white target beside a dark area
    f = calibrate(img, method="study")
    assert np.allclose(f, (255 / 100, 255 / 200, 255 / 150), rtol=1e-6)
    with pytest.raises(ValueError):
        calibrate(img, method="gray-world")


def test_preprocess_decodes_and_clips():
    raw = np.full((244, 324), 200, np.uint8)
    out = preprocess(raw, (2.0, 1.0, 0.5))
    assert out.shape == (244, 324, 3) and out.dtype == np.uint8
    assert tuple(out[100, 100]) == (255, 200, 100)
    assert decode_raw(out) is out


def test_rig_line_is_edited_in_place(tmp_path):
    text = (
        "# comment\nsensors:\n  mocap:\n    enabled: true\n  camera:\n    rate_hz: 15\n"
        "    white_balance: [1.0, 1.0, 1.0]  # keep me\n\nwind: {}\n"
    )
    new = write_rig_factors(text, (1.5, 1.0, 1.25))
    assert new == text.replace("[1.0, 1.0, 1.0]", "[1.5000, 1.0000, 1.2500]")
    missing = text.replace("    white_balance: [1.0, 1.0, 1.0]  # keep me\n", "")
    added = write_rig_factors(missing, (2.0, 1.0, 1.0))
    assert "    rate_hz: 15\n    white_balance: [2.0000, 1.0000, 1.0000]" in added
    assert added.endswith("\nwind: {}\n")


def test_cli_calibrates_into_a_rig_copy(tmp_path, capsys, repo):
    rig = tmp_path / "sim.yaml"
    shutil.copy(os.path.join(repo, "rigs", "sim.yaml"), rig)
    rig.write_text(write_rig_factors(rig.read_text(), (1.0, 1.0, 1.0)))
    before = rig.read_text()
    assert main(["calibrate", "--rig", str(rig)]) == 0
    after = rig.read_text()
    assert "white balance factors (B, G, R)" in capsys.readouterr().out
    changed = [
        (a, b) for a, b in zip(before.splitlines(), after.splitlines(), strict=True) if a != b
    ]
    assert len(changed) == 1 and "white_balance:" in changed[0][1]
    import yaml

    f = yaml.safe_load(after)["sensors"]["camera"]["white_balance"]
    assert f[0] > f[2] > f[1] > 1.0  # blue weakest on the raw sensor, green strongest
