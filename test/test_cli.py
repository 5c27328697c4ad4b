"""The ``gap-validate`` CLI: compare-models on the paper's example, JSON keys, one-line errors, exit codes."""
import json
import os
import subprocess
import sys

import pytest

from gap_validation.cli.main import main

P1 = "config/paper_example_p1.yaml"
P2 = "config/paper_example_p2.yaml"


def test_compare_models_paper_example(tmp_path, capsys):
    out_json = tmp_path / "out.json"
    assert main(["compare-models", P1, P2, "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.startswith("pitch"))
    cells = row.split()
    assert cells[1] == "0.0852"          # nu-gap (paper prints 0.09)
    assert cells[3] == "0.1404"          # epsilon (paper prints 0.14)
    data = json.loads(out_json.read_text())["channels"]["pitch"]
    assert round(data["nu_gap"], 3) == 0.085 and round(data["epsilon"], 3) == 0.140
    assert data["worst_frequency_rad_s"] == pytest.approx(14.9, abs=0.2)
    assert data["gain_margin_db"] == pytest.approx(2.45, abs=0.01)
    assert data["phase_margin_deg"] == pytest.approx(16.1, abs=0.05)
    assert [round(m, 2) for m in data["disk_markers"]] == [0.75, 1.33]
    for key in ("nu_gap", "epsilon", "worst_frequency_rad_s", "gain_margin_db", "phase_margin_deg",
                "disk_margin"):
        assert key in data


def test_compare_models_same_model_is_zero(capsys):
    assert main(["compare-models", P1, P1]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("pitch"))
    assert row.split()[1] == "0.0000"


@pytest.mark.parametrize("content,needle", [
    ("channels: {pitch: {input: {topic: /a, field: x}, output: {topic: /b, field: y}, "
     "model: {numerator: [1], denominator: [1, 'q']}}}", "denominator"),
    ("channels: [1, 2]", "channels"),
    ("channels:\n  pitch: {input: [\n", "YAML error"),
])
def test_bad_config_is_one_line_exit_2(tmp_path, capsys, content, needle):
    bad = tmp_path / "bad.yaml"
    bad.write_text(content)
    assert main(["compare-models", P1, str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(bad) in err and needle in err


def test_missing_config_exit_2(capsys):
    assert main(["compare-models", P1, "no/such/file.yaml"]) == 2
    assert "no/such/file.yaml: config file not found" in capsys.readouterr().err


def test_console_script_runs():
    """The installed console script exists and answers --help (setup.py entry point)."""
    exe = os.path.join(os.path.dirname(sys.executable), "gap-validate")
    if not os.path.exists(exe):
        pytest.skip("gap-validate console script not installed in this environment")
    proc = subprocess.run([exe, "--help"], capture_output=True, text=True, env=os.environ.copy(), timeout=60)
    assert proc.returncode == 0 and "compare-models" in proc.stdout


def test_ctrl_c_while_starting_up_is_one_line_exit_130(capsys, monkeypatch):
    import gap_validation.cli.main as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["compare-models", "a.yaml", "b.yaml"]) == 130
    assert capsys.readouterr().err.strip() == "gap-validate: interrupted"
