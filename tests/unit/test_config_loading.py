"""Config errors are one line naming file, key, value and rule (config_loading + controller configs)."""

from __future__ import annotations

import shutil

import pytest

from mavastsm.config_loading import packaged_config_dir, parse_overrides, resolve_config
from mavastsm.control import make_controller
from mavastsm.errors import ConfigError
from mavastsm.solo_model import load_solo

SOLO = load_solo()


def copy_config(tmp_path, name="smc.yaml"):
    dst = tmp_path / name
    shutil.copyfile(packaged_config_dir() / "controllers" / name, dst)
    return dst


def one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError) as exc:
        make_controller("smc", SOLO, config=tmp_path / "nope.yaml")
    assert "nope.yaml" in one_line(exc)


def test_malformed_yaml(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("gains:\n  surface_slope: {value: [1, 2\n")
    with pytest.raises(ConfigError) as exc:
        make_controller("smc", SOLO, config=bad)
    assert "malformed YAML" in one_line(exc) and "bad.yaml" in str(exc.value)


def test_negative_gain_in_file(tmp_path):
    cfg = copy_config(tmp_path)
    cfg.write_text(cfg.read_text().replace("value: [75.6, 45.3, 32.1]", "value: [-75.6, 45.3, 32.1]"))
    with pytest.raises(ConfigError) as exc:
        make_controller("smc", SOLO, config=cfg)
    msg = one_line(exc)
    assert str(cfg) in msg and "gains.switching_gain" in msg and "-75.6" in msg and ">= 0.0" in msg


def test_negative_gain_override():
    with pytest.raises(ConfigError, match=r"gains.mu.*-0.01.*must be > 0.0"):
        make_controller("astsm", SOLO, overrides={"mu": -0.01})


def test_bad_choice():
    with pytest.raises(ConfigError, match=r"gains.gain_units.*'newton'.*must be one of \['torque', 'accel'\]"):
        make_controller("astsm", SOLO, overrides={"gain_units": "newton"})


def test_unknown_key_in_file(tmp_path):
    cfg = copy_config(tmp_path)
    cfg.write_text(cfg.read_text() + "  boost:\n    value: 1.0\n    unit: '-'\n")
    with pytest.raises(ConfigError) as exc:
        make_controller("smc", SOLO, config=cfg)
    assert "unknown key(s) gains.boost" in one_line(exc)


def test_unknown_override_key():
    with pytest.raises(ConfigError, match="override 'gains.boost' names no parameter"):
        make_controller("smc", SOLO, overrides={"boost": 1.0})


def test_missing_key(tmp_path):
    cfg = copy_config(tmp_path)
    text = cfg.read_text()
    start = text.index("  boundary_layer:")
    end = text.index("  torque_limit_enabled:")
    cfg.write_text(text[:start] + text[end:])
    with pytest.raises(ConfigError, match="missing key 'gains.boundary_layer'"):
        make_controller("smc", SOLO, config=cfg)


def test_parameter_without_unit(tmp_path):
    cfg = copy_config(tmp_path)
    cfg.write_text(cfg.read_text().replace('    unit: "rad/s"\n    symbol: "φ"', '    symbol: "φ"'))
    with pytest.raises(ConfigError, match="boundary_layer.*'unit'"):
        make_controller("smc", SOLO, config=cfg)


def test_cross_field_rule():
    with pytest.raises(ConfigError, match=r"gains.alpha_max.*must be > alpha_min"):
        make_controller("astsm", SOLO, overrides={"alpha_max": 0.005})


def test_resolve_lists_packaged_choices():
    with pytest.raises(ConfigError, match="packaged controllers: .*astsm_paper.*smc"):
        resolve_config("nonexistent", "controllers")


def test_parse_overrides():
    assert parse_overrides(["mu=0.03", "surface_slope=[1, 2, 3]", "gain_units=torque"]) == {
        "mu": 0.03, "surface_slope": [1, 2, 3], "gain_units": "torque"}
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_overrides(["mu"])


def test_every_packaged_controller_config_loads():
    for path in sorted((packaged_config_dir() / "controllers").glob("*.yaml")):
        key = "pid" if path.stem.startswith("pid") else path.stem.split("_")[0]
        make_controller(key, SOLO, config=path.stem)
