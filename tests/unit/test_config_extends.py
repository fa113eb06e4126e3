"""Presets as deltas of a base (issue 19, item 5): ``extends: <preset>`` in a controller config.

The four ASTSM presets and pid_fair were ~95-line copies differing in 1-3 values; they are now deltas. The
resolved parameters must be exactly the values the full copies had (snapshot below, taken from the full files
before the rewrite), and a broken delta is one line naming file and key, exit 2 at start-up as in check-config.
"""

from __future__ import annotations

import dataclasses

import pytest

from mavastsm.cli import main
from mavastsm.config_loading import load_section, packaged_config_dir, read_config, resolve_config
from mavastsm.control import make_controller
from mavastsm.errors import ConfigError
from mavastsm.solo_model import load_solo

GAINS_TODAY = {'astsm': {'alpha_max': (1000.0, 1000.0, 1000.0),
           'alpha_min': (0.01, 0.01, 0.01),
           'beta_offset': 0.0,
           'epsilon': (0.6, 0.6, 0.6),
           'eta': 0.01,
           'gain_units': 'accel',
           'gamma1': 6.6,
           'mu': (0.01, 0.01, 0.01),
           'surface_slope': (3.89, 3.89, 4.36),
           'torque_limit_enabled': False,
           'torque_limit_nm': (2.9, 2.9, 0.4),
           'varpi': 1000.0},
 'astsm_400hz': {'alpha_max': (1000.0, 1000.0, 1000.0),
                 'alpha_min': (0.01, 0.01, 0.01),
                 'beta_offset': 0.0,
                 'epsilon': (0.6, 0.6, 0.6),
                 'eta': 0.01,
                 'gain_units': 'accel',
                 'gamma1': 6.6,
                 'mu': (0.03, 0.03, 0.03),
                 'surface_slope': (3.89, 3.89, 4.36),
                 'torque_limit_enabled': False,
                 'torque_limit_nm': (2.9, 2.9, 0.4),
                 'varpi': 1000.0},
 'astsm_mavlink': {'alpha_max': (1000.0, 1000.0, 1000.0),
                   'alpha_min': (5.0, 5.0, 5.0),
                   'beta_offset': 0.0,
                   'epsilon': (0.6, 0.6, 0.6),
                   'eta': 0.01,
                   'gain_units': 'accel',
                   'gamma1': 6.6,
                   'mu': (0.06, 0.06, 0.06),
                   'surface_slope': (3.89, 3.89, 4.36),
                   'torque_limit_enabled': False,
                   'torque_limit_nm': (2.9, 2.9, 0.4),
                   'varpi': 100.0},
 'astsm_paper': {'alpha_max': (50.0, 50.0, 50.0),
                 'alpha_min': (0.01, 0.01, 0.01),
                 'beta_offset': 0.0,
                 'epsilon': (0.6, 0.6, 0.6),
                 'eta': 0.01,
                 'gain_units': 'torque',
                 'gamma1': 6.6,
                 'mu': (0.01, 0.01, 0.01),
                 'surface_slope': (3.89, 3.89, 4.36),
                 'torque_limit_enabled': False,
                 'torque_limit_nm': (2.9, 2.9, 0.4),
                 'varpi': 200.0},
 'pid': {'angle_p': (4.5, 4.5, 3.42),
         'd_filter_hz': 20.0,
         'imax': (0.444, 0.444, 0.1),
         'output_clip_enabled': True,
         'rate_d': (0.0036, 0.0036, 0.0),
         'rate_feedforward_enabled': True,
         'rate_i': (0.09, 0.09, 0.092),
         'rate_p': (0.135, 0.135, 0.92),
         'torque_limit_enabled': False,
         'torque_limit_nm': (2.9, 2.9, 0.4),
         'torque_scale_nm': (2.9, 2.9, 0.4)},
 'pid_fair': {'angle_p': (4.5, 4.5, 3.42),
              'd_filter_hz': 20.0,
              'imax': (1.0, 1.0, 1.0),
              'output_clip_enabled': False,
              'rate_d': (0.0036, 0.0036, 0.0),
              'rate_feedforward_enabled': True,
              'rate_i': (0.09, 0.09, 0.092),
              'rate_p': (0.135, 0.135, 0.92),
              'torque_limit_enabled': False,
              'torque_limit_nm': (2.9, 2.9, 0.4),
              'torque_scale_nm': (2.9, 2.9, 0.4)}}

PARAMETERS_TODAY = {'astsm': {'alpha_max': (1000.0, 'rad/s^2', 'α_max', (0.0, 100000.0), None),
           'alpha_min': (0.01, 'rad/s^2', 'α_m (eq. 34)', (0.0, 1000.0), None),
           'beta_offset': (0.0, 'rad/s^2', 'λ + 4ε² in Shtessel 2012 (eq. 35 drops it)', (0.0, 1000.0), None),
           'epsilon': (0.6, '-', 'ε (eq. 35)', (0.0, 100.0), None),
           'eta': (0.01, 'rad/s^2/s', 'η (eq. 34)', (0.0, 1000.0), None),
           'gain_units': ('accel', '-', '', None, ('torque', 'accel')),
           'gamma1': (6.6, '-', 'γ1 (eq. 34)', (0.0, 1000.0), None),
           'mu': (0.01, 'rad/s', 'μ (eq. 34)', (0.0, 10.0), None),
           'surface_slope': ((3.89, 3.89, 4.36), '1/s', 'Λ = diag(λφ, λθ, λψ) (eq. 19)', (0.0, 100.0), None),
           'torque_limit_enabled': (False, '-', '', None, None),
           'torque_limit_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_max', (0.0, 100.0), None),
           'varpi': (1000.0, '-', 'ϖ (eq. 34)', (0.0, 100000.0), None)},
 'astsm_400hz': {'alpha_max': (1000.0, 'rad/s^2', 'α_max', (0.0, 100000.0), None),
                 'alpha_min': (0.01, 'rad/s^2', 'α_m (eq. 34)', (0.0, 1000.0), None),
                 'beta_offset': (0.0, 'rad/s^2', 'λ + 4ε² in Shtessel 2012 (eq. 35 drops it)', (0.0, 1000.0), None),
                 'epsilon': (0.6, '-', 'ε (eq. 35)', (0.0, 100.0), None),
                 'eta': (0.01, 'rad/s^2/s', 'η (eq. 34)', (0.0, 1000.0), None),
                 'gain_units': ('accel', '-', '', None, ('torque', 'accel')),
                 'gamma1': (6.6, '-', 'γ1 (eq. 34)', (0.0, 1000.0), None),
                 'mu': (0.03, 'rad/s', 'μ (eq. 34)', (0.0, 10.0), None),
                 'surface_slope': ((3.89, 3.89, 4.36), '1/s', 'Λ = diag(λφ, λθ, λψ) (eq. 19)', (0.0, 100.0), None),
                 'torque_limit_enabled': (False, '-', '', None, None),
                 'torque_limit_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_max', (0.0, 100.0), None),
                 'varpi': (1000.0, '-', 'ϖ (eq. 34)', (0.0, 100000.0), None)},
 'astsm_mavlink': {'alpha_max': (1000.0, 'rad/s^2', 'α_max', (0.0, 100000.0), None),
                   'alpha_min': (5.0, 'rad/s^2', 'α_m (eq. 34)', (0.0, 1000.0), None),
                   'beta_offset': (0.0, 'rad/s^2', 'λ + 4ε² in Shtessel 2012 (eq. 35 drops it)', (0.0, 1000.0), None),
                   'epsilon': (0.6, '-', 'ε (eq. 35)', (0.0, 100.0), None),
                   'eta': (0.01, 'rad/s^2/s', 'η (eq. 34)', (0.0, 1000.0), None),
                   'gain_units': ('accel', '-', '', None, ('torque', 'accel')),
                   'gamma1': (6.6, '-', 'γ1 (eq. 34)', (0.0, 1000.0), None),
                   'mu': (0.06, 'rad/s', 'μ (eq. 34)', (0.0, 10.0), None),
                   'surface_slope': ((3.89, 3.89, 4.36), '1/s', 'Λ = diag(λφ, λθ, λψ) (eq. 19)', (0.0, 100.0), None),
                   'torque_limit_enabled': (False, '-', '', None, None),
                   'torque_limit_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_max', (0.0, 100.0), None),
                   'varpi': (100.0, '-', 'ϖ (eq. 34)', (0.0, 100000.0), None)},
 'astsm_paper': {'alpha_max': (50.0, 'N m', 'α_max', (0.0, 100000.0), None),
                 'alpha_min': (0.01, 'N m', 'α_m (eq. 34)', (0.0, 1000.0), None),
                 'beta_offset': (0.0, 'N m', 'λ + 4ε² in Shtessel 2012 (eq. 35 drops it)', (0.0, 1000.0), None),
                 'epsilon': (0.6, '-', 'ε (eq. 35)', (0.0, 100.0), None),
                 'eta': (0.01, 'N m/s', 'η (eq. 34)', (0.0, 1000.0), None),
                 'gain_units': ('torque', '-', '', None, ('torque', 'accel')),
                 'gamma1': (6.6, '-', 'γ1 (eq. 34)', (0.0, 1000.0), None),
                 'mu': (0.01, 'rad/s', 'μ (eq. 34)', (0.0, 10.0), None),
                 'surface_slope': ((3.89, 3.89, 4.36), '1/s', 'Λ = diag(λφ, λθ, λψ) (eq. 19)', (0.0, 100.0), None),
                 'torque_limit_enabled': (False, '-', '', None, None),
                 'torque_limit_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_max', (0.0, 100.0), None),
                 'varpi': (200.0, '-', 'ϖ (eq. 34)', (0.0, 100000.0), None)},
 'pid': {'angle_p': ((4.5, 4.5, 3.42), '1/s', 'ATC_ANG_RLL_P/PIT_P/YAW_P', (0.0, 100.0), None),
         'd_filter_hz': (20.0, 'Hz', 'ATC_RAT_*_FILT', (0.1, 1000.0), None),
         'imax': ((0.444, 0.444, 0.1), '-', 'ATC_RAT_*_IMAX', (0.0, 10.0), None),
         'output_clip_enabled': (True, '-', '', None, None),
         'rate_d': ((0.0036, 0.0036, 0.0), 's/rad', 'ATC_RAT_*_D', (0.0, 1.0), None),
         'rate_feedforward_enabled': (True, '-', 'ATC_RATE_FF_ENAB', None, None),
         'rate_i': ((0.09, 0.09, 0.092), '1/rad', 'ATC_RAT_*_I', (0.0, 10.0), None),
         'rate_p': ((0.135, 0.135, 0.92), '1/(rad/s)', 'ATC_RAT_*_P', (0.0, 10.0), None),
         'torque_limit_enabled': (False, '-', '', None, None),
         'torque_limit_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_max', (0.0, 100.0), None),
         'torque_scale_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_scale', (0.0, 100.0), None)},
 'pid_fair': {'angle_p': ((4.5, 4.5, 3.42), '1/s', 'ATC_ANG_RLL_P/PIT_P/YAW_P', (0.0, 100.0), None),
              'd_filter_hz': (20.0, 'Hz', 'ATC_RAT_*_FILT', (0.1, 1000.0), None),
              'imax': ((1.0, 1.0, 1.0), '-', 'ATC_RAT_*_IMAX', (0.0, 10.0), None),
              'output_clip_enabled': (False, '-', '', None, None),
              'rate_d': ((0.0036, 0.0036, 0.0), 's/rad', 'ATC_RAT_*_D', (0.0, 1.0), None),
              'rate_feedforward_enabled': (True, '-', 'ATC_RATE_FF_ENAB', None, None),
              'rate_i': ((0.09, 0.09, 0.092), '1/rad', 'ATC_RAT_*_I', (0.0, 10.0), None),
              'rate_p': ((0.135, 0.135, 0.92), '1/(rad/s)', 'ATC_RAT_*_P', (0.0, 10.0), None),
              'torque_limit_enabled': (False, '-', '', None, None),
              'torque_limit_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_max', (0.0, 100.0), None),
              'torque_scale_nm': ((2.9, 2.9, 0.4), 'N m', 'τ_scale', (0.0, 100.0), None)}}

LAW = {"astsm": "astsm", "astsm_400hz": "astsm", "astsm_paper": "astsm", "astsm_mavlink": "astsm", "pid": "pid", "pid_fair": "pid_fair"}


@pytest.mark.parametrize("preset", sorted(GAINS_TODAY))
def test_resolved_presets_are_the_values_they_had_as_full_copies(preset):
    gains = make_controller(LAW[preset], load_solo(), config=preset).gains
    assert dataclasses.asdict(gains) == GAINS_TODAY[preset]
    params = load_section(resolve_config(preset, "controllers"), "gains")
    assert {k: (p.value, p.unit, p.symbol, p.range, p.choices) for k, p in params.items()} == PARAMETERS_TODAY[preset]


def test_derived_presets_are_short_deltas():
    for preset, base in (("astsm_400hz", "astsm"), ("astsm_paper", "astsm"), ("astsm_mavlink", "astsm_400hz"), ("pid_fair", "pid")):
        path = packaged_config_dir() / "controllers" / f"{preset}.yaml"
        text = path.read_text(encoding="utf-8")
        assert f"extends: {base}" in text and len(text.splitlines()) < 30, preset
        assert "extends" not in read_config(path)


def _write(tmp_path, name, text):
    path = tmp_path / f"{name}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def _one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_a_delta_next_to_its_base_and_a_packaged_base(tmp_path):
    _write(tmp_path, "mine", "extends: astsm\ngains:\n  mu: {value: 0.02}\n")
    child = _write(tmp_path, "child", "extends: mine\ngains:\n  varpi: {value: 500.0}\n")
    gains = make_controller("astsm", load_solo(), config=child).gains
    assert gains.mu == (0.02, 0.02, 0.02) and gains.varpi == 500.0 and gains.gamma1 == 6.6


def test_unknown_base(tmp_path):
    path = _write(tmp_path, "astsm_x", "extends: no_such_preset\ngains:\n  mu: {value: 0.02}\n")
    with pytest.raises(ConfigError) as exc:
        make_controller("astsm", load_solo(), config=path)
    msg = _one_line(exc)
    assert str(path) in msg and "extends" in msg and "no_such_preset" in msg


def test_cycle(tmp_path):
    a = _write(tmp_path, "astsm_a", "extends: astsm_b\ngains:\n  mu: {value: 0.02}\n")
    _write(tmp_path, "astsm_b", "extends: astsm_a\ngains:\n  mu: {value: 0.03}\n")
    with pytest.raises(ConfigError) as exc:
        make_controller("astsm", load_solo(), config=a)
    msg = _one_line(exc)
    assert str(a) in msg and "cycle" in msg and "astsm_a -> astsm_b -> astsm_a" in msg


def test_key_the_base_does_not_have(tmp_path):
    path = _write(tmp_path, "astsm_x", "extends: astsm\ngains:\n  boost: {value: 1.0}\n")
    with pytest.raises(ConfigError) as exc:
        make_controller("astsm", load_solo(), config=path)
    msg = _one_line(exc)
    assert str(path) in msg and "gains.boost" in msg and "not in base 'astsm'" in msg


def test_a_delta_value_is_validated_like_any_value(tmp_path):
    path = _write(tmp_path, "astsm_x", "extends: astsm\ngains:\n  mu: {value: -0.02}\n")
    with pytest.raises(ConfigError, match=r"gains.mu.*-0.02.*must be > 0.0"):
        make_controller("astsm", load_solo(), config=path)


@pytest.mark.parametrize("text,rule", [
    ("extends: no_such_preset\ngains:\n  mu: {value: 0.02}\n", "no_such_preset"),
    ("extends: astsm\ngains:\n  boost: {value: 1.0}\n", "gains.boost"),
    ("extends: astsm_x\ngains:\n  mu: {value: 0.02}\n", "cycle"),
])
def test_start_up_and_check_config_reject_a_broken_delta_with_exit_2(tmp_path, capsys, text, rule):
    path = _write(tmp_path, "astsm_x", text)
    for argv in (["check-config", str(path)], ["connect", "udpout:127.0.0.1:9", "--controller-config", str(path)],
                 ["simulate", "--controller", f"astsm:{path}", "--scenario", "nominal"]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0] and rule in err[0], (argv, err)


def test_check_config_shows_the_resolved_values(capsys):
    assert main(["check-config", "controllers/astsm_mavlink"]) == 0
    out = capsys.readouterr().out
    assert "extends" in out and "astsm_400hz.yaml" in out and "astsm.yaml" in out
    rows = {line.split("│")[1].strip(): line.split("│")[2].strip() for line in out.splitlines() if line.count("│") > 3}
    assert rows["mu *"] == "0.06" and rows["varpi *"] == "100" and rows["gamma1"] == "6.6" and rows["surface_slope"] == "3.89, 3.89, 4.36"
