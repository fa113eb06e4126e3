"""``mavastsm simulate`` and ``mavastsm reproduce`` end to end (in-process, time-compressed scenarios)."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import pytest

from mavastsm import cli
from mavastsm.offline import commands, reproduction


@pytest.fixture
def short_scenario(tmp_path):
    f = tmp_path / "short.yaml"
    f.write_text("scenario:\n  reference: paper_steps\n  duration_s: 0.8\n"
                 "  disturbances:\n    - {type: step, start_s: 0.6, torque_nm: [0.5, 0.5, 0.5]}\n")
    return f


def test_simulate_writes_csv_and_plot(tmp_path, short_scenario, capsys):
    out_csv, out_png = tmp_path / "o" / "run.csv", tmp_path / "o" / "run.png"
    plot = ["--plot", str(out_png)] if commands.matplotlib_available() else []  # the plot extra is optional (.ci installs only [test])
    rc = cli.main(["simulate", "--controller", "astsm,astsm:astsm_paper,pid", "--scenario", str(short_scenario),
                   "--dt-ms", "2.5", "--csv", str(out_csv), *plot])
    assert rc == 0
    text = capsys.readouterr().out
    assert "simulated 2.4 s of flight" in text  # 3 runs x 0.8 s
    rows = list(csv.DictReader(open(out_csv)))
    assert {r["controller"] for r in rows} == {"astsm", "astsm[astsm_paper]", "pid"}
    assert len(rows) == 3 * 320  # 0.8 s at 2.5 ms = 320 samples each (the 2 ms stride keeps every sample)
    assert float(rows[-1]["roll_ref_deg"]) == pytest.approx(-10.0)
    if plot:
        assert out_png.stat().st_size > 10_000


def test_simulate_plot_without_matplotlib_is_an_error_that_says_how_to_install(tmp_path, short_scenario, capsys, monkeypatch):
    """The ux issue, item 10: `simulate --plot` without matplotlib exited 0 having made no plot. Asking for a figure
    that cannot be made is now a one-line error before anything runs, exit 2."""
    monkeypatch.setattr(commands, "matplotlib_available", lambda: False)
    out_png = tmp_path / "x.png"
    assert cli.main(["simulate", "--scenario", str(short_scenario), "--dt-ms", "5", "--plot", str(out_png)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "--plot" in err[0] and 'pip install "mavastsm[plot]"' in err[0], err
    assert "simulated" not in captured.out and not out_png.exists()


def test_simulate_override_is_applied(short_scenario, capsys):
    assert cli.main(["simulate", "--scenario", str(short_scenario), "--dt-ms", "5", "--set", "mu=0.05"]) == 0


def tiny_plans(compressed):
    def plan(modes, period):
        plans = reproduction.plan_modes(modes, period)
        return [replace(p, dt_s=2e-3,
                        specs=tuple(replace(s, scenario=compressed(s.scenario.name, 0.1)) for s in p.specs),
                        sweep_specs=tuple(replace(s, scenario=compressed("disturbance", 0.1)) for s in p.sweep_specs))
                for p in plans]
    return plan


def test_reproduce_end_to_end_on_compressed_scenarios(tmp_path, capsys, monkeypatch, compressed):
    monkeypatch.setattr(commands, "plan_modes", tiny_plans(compressed))
    out, docs = tmp_path / "rep", tmp_path / "docs" / "reproduction.md"
    assert cli.main(["reproduce", "--out", str(out), "--docs", str(docs), "--workers", "2", "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "claims passed: mode P:" in text and "mode E1:" in text
    claims = list(csv.DictReader(open(out / "claims.csv")))
    assert [c["claim"] for c in claims] == [f"C{i}" for i in range(1, 9)] * 2
    assert all(c["verdict"] in ("PASS", "FAIL", "INCONCLUSIVE") and c["measured"] for c in claims)
    metrics = list(csv.DictReader(open(out / "metrics.csv")))
    assert {m["mode"] for m in metrics} == {"P", "E1"} and "settling_2pct_s" in metrics[0]
    md = docs.read_text()
    assert "## Claims C1–C8" in md and "| **C8**" in md and "Where our results differ" in md
    assert not (out / "figures").exists() and "## Figures" not in md


def test_reproduce_single_worker_with_figures(tmp_path, monkeypatch, compressed):
    monkeypatch.setattr(commands, "plan_modes", tiny_plans(compressed))
    docs = tmp_path / "docs" / "r.md"
    assert cli.main(["reproduce", "--out", str(tmp_path / "rep"), "--workers", "1", "--modes", "E1", "--docs", str(docs)]) == 0
    names = sorted(p.name for p in (tmp_path / "rep" / "figures").iterdir())
    assert names == sorted(f"fig{i}_{n}_E1.png" for i, n in ((3, "nominal"), (4, "disturbance_yaw"), (5, "roll_input"), (6, "variation"), (7, "alpha3")))
    assert (docs.parent / "figures" / "fig7_alpha3_E1.png").is_file()
    assert "figures/fig3_nominal_E1.png" in docs.read_text()


def test_every_reproduction_figure_labels_its_axes_with_units_and_shows_every_trace(tmp_path, monkeypatch, compressed):
    """The ux issue, item 12: fig3 had no time-axis label and ATSM's chattering band hid ASTSM; fig7's α3 had no
    unit and its x-axis ran past the data. Every figure's panels are checked as they are saved."""
    import re

    import matplotlib.figure

    unit = re.compile(r"\[[^\]]+\]")
    saved = {}
    real_savefig = matplotlib.figure.Figure.savefig

    def recording_savefig(fig, path, *args, **kwargs):
        saved[Path(path).name.split("_E1")[0]] = fig
        return real_savefig(fig, path, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", recording_savefig)
    monkeypatch.setattr(commands, "plan_modes", tiny_plans(compressed))
    assert cli.main(["reproduce", "--out", str(tmp_path / "rep"), "--workers", "1", "--modes", "E1"]) == 0
    assert sorted(saved) == ["fig3_nominal", "fig4_disturbance_yaw", "fig5_roll_input", "fig6_variation", "fig7_alpha3"]
    for name, fig in saved.items():
        for ax in fig.axes:
            assert unit.search(ax.get_ylabel()), (name, ax.get_ylabel())
            # a time axis is labelled, on this panel or on the one below it that shares it
            below = [o for o in fig.axes if o is not ax and ax.get_shared_x_axes().joined(ax, o) and o.get_xlabel()]
            assert ax.get_xlabel() == "t [s]" or below, (name, ax.get_ylabel())
    for ax in saved["fig7_alpha3"].axes:  # α3 carries its unit, and each panel ends with its own data
        assert re.search(r"α3 \[(N·m|rad/s\^2)\]", ax.get_ylabel())
        t_end = max(line.get_xdata()[-1] for line in ax.get_lines())
        assert ax.get_xlim()[1] == pytest.approx(t_end)
    for ax in saved["fig3_nominal"].axes:  # ASTSM drawn last and solid; the others translucent under it
        lines = {line.get_label(): line for line in ax.get_lines()}
        others = [line for label, line in lines.items() if label not in ("astsm", "reference")]
        assert others and all(line.get_zorder() < lines["astsm"].get_zorder() for line in others)
        assert all((line.get_alpha() or 1.0) < 1.0 for line in others) and (lines["astsm"].get_alpha() or 1.0) == 1.0
