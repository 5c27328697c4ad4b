"""The ``gap-validate`` CLI: compare-models on the paper's example, JSON keys, one-line errors, exit codes."""
import copy
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


# -- MIMO channels and the controller check (issue 14)
# ---------------------------------------------------------

SURFACES = [{"topic": "/control_surfaces", "field": "position[aileron]"},
            {"topic": "/control_surfaces", "field": "position[rudder]"}]
RATES = [{"topic": "/imu", "field": "angular_velocity.x"}, {"topic": "/imu", "field": "angular_velocity.z"}]


def rotated_block_diagonal(first, second, angle_out=0.7, angle_in=-1.9):
    """U diag(first, second) V as state-space lists (first, second: (num, den) of SISO models)."""
    import numpy as np
    import scipy.signal

    def rotation(angle):
        return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])

    (a1, b1, c1, d1), (a2, b2, c2, d2) = (scipy.signal.tf2ss(*tf) for tf in (first, second))
    n1, n = a1.shape[0], a1.shape[0] + a2.shape[0]
    a, b, c = np.zeros((n, n)), np.zeros((n, 2)), np.zeros((2, n))
    a[:n1, :n1], a[n1:, n1:] = a1, a2
    b[:n1, :1], b[n1:, 1:] = b1, b2
    c[:1, :n1], c[1:, n1:] = c1, c2
    u, v = rotation(angle_out), rotation(angle_in)
    d = u @ np.diag([d1[0, 0], d2[0, 0]]) @ v
    return {"A": a.tolist(), "B": (b @ v).tolist(), "C": (u @ c).tolist(), "D": d.tolist()}


def write_mimo(path, state_space, controller=None, swap=False):
    import yaml

    channel = {"inputs": SURFACES[::-1] if swap else SURFACES, "outputs": RATES[::-1] if swap else RATES,
               "model": {"state_space": state_space}}
    if swap:  # the same model, its inputs and outputs listed the other way round
        import numpy as np

        flip = np.array([[0.0, 1.0], [1.0, 0.0]])
        ss = {k: np.array(v) for k, v in state_space.items()}
        channel["model"]["state_space"] = {
            "A": ss["A"].tolist(),
            "B": (ss["B"] @ flip).tolist(),
            "C": (flip @ ss["C"]).tolist(),
            "D": (flip @ ss["D"] @ flip).tolist(),
        }
    if controller is not None:
        channel["controller"] = controller
    path.write_text(yaml.safe_dump({"channels": {"lateral": channel}}))
    return str(path)


EQ18, EQ19 = ([18.75, 225.0], [1.0, 9.0, 225.0]), ([18.75, 225.0], [1.0, 7.22, 246.5])


def test_compare_models_mimo_rotated_block_diagonal_is_0_0852(tmp_path, capsys):
    a = write_mimo(tmp_path / "a.yaml", rotated_block_diagonal(EQ18, ([100.0], [2.0, 1.0])))
    b = write_mimo(tmp_path / "b.yaml", rotated_block_diagonal(EQ19, ([100.0], [2.0, -1.0])))
    out_json = tmp_path / "out.json"
    assert main(["compare-models", a, b, "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.startswith("lateral"))
    assert row.split()[:3] == ["lateral", "(2x2)", "0.0852"]
    assert "defined for SISO channels" in text
    data = json.loads(out_json.read_text())["channels"]["lateral"]
    assert data["nu_gap"] == pytest.approx(0.0852, abs=1e-4)
    assert data["nu_gap_frequency_rad_s"] == pytest.approx(14.93, abs=0.01)
    assert data["shape"] == [2, 2] and data["epsilon"] is None and data["gain_margin_db"] is None
    assert data["nu_gap_note"] is None
    # B lists the same signals in the other order: matched by topic and field, the same nu-gap
    swapped = write_mimo(
        tmp_path / "swapped.yaml", rotated_block_diagonal(EQ19, ([100.0], [2.0, -1.0])), swap=True
    )
    assert main(["compare-models", a, swapped, "--json", str(out_json)]) == 0
    assert json.loads(out_json.read_text())["channels"]["lateral"]["nu_gap"] == pytest.approx(data["nu_gap"],
                                                                                                rel=1e-9)


def test_compare_models_mimo_with_a_controller(tmp_path, capsys):
    # u = -C y with C = V^T diag(1, 1) U^T: unit feedback per block in the rotated coordinates (b = 0.696)
    import numpy as np

    u, v = (np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]]) for t in (0.7, -1.9))
    gain = (v.T @ np.diag([1.0, 1.0]) @ u.T).tolist()
    a = write_mimo(tmp_path / "a.yaml", rotated_block_diagonal(EQ18, ([100.0], [2.0, 1.0])),
                   controller={"state_space": {"D": gain}})
    b = write_mimo(tmp_path / "b.yaml", rotated_block_diagonal(EQ19, ([100.0], [2.0, -1.0])))
    out_json = tmp_path / "out.json"
    assert main(["compare-models", a, b, "--json", str(out_json)]) == 0
    data = json.loads(out_json.read_text())["channels"]["lateral"]
    assert data["stability_margin_b"] == pytest.approx(0.6962, abs=1e-4)
    assert data["stability_margin_b"] > data["nu_gap"] and data["guaranteed_stable"] is True
    assert data["stability_note"].startswith("the controller is guaranteed to stabilise the aircraft: b = ")
    assert "guaranteed" in capsys.readouterr().out


def siso_yaml(path, num, den, controller=None):
    channel = {"input": SURFACES[0], "output": RATES[0], "model": {"numerator": num, "denominator": den}}
    if controller:
        channel["controller"] = controller
    import yaml

    path.write_text(yaml.safe_dump({"channels": {"roll": channel}}))
    return str(path)


@pytest.mark.parametrize("num, den, guaranteed", [([1.0], [1.0, 0.01], True), ([-1.0], [1.0, 0.0], False)])
def test_compare_models_controller_check_b_of_the_integrator_with_unit_feedback(tmp_path, capsys, num, den,
                                                                                guaranteed):
    a = siso_yaml(
        tmp_path / "a.yaml", [1.0], [1.0, 0.0], controller={"numerator": [1.0], "denominator": [1.0]}
    )
    b = siso_yaml(tmp_path / "b.yaml", num, den)
    out_json = tmp_path / "out.json"
    assert main(["compare-models", a, b, "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    data = json.loads(out_json.read_text())["channels"]["roll"]
    assert data["stability_margin_b"] == pytest.approx(0.70711, abs=5e-6)
    assert data["guaranteed_stable"] is guaranteed
    assert ("guaranteed to stabilise the aircraft: b = 0.7071 > nu-gap 0.0100" in text) is guaranteed
    header = text.splitlines()[0].split()
    assert header[-2:] == ["b(P1,C)", "stable"]


def test_compare_models_shape_mismatch_is_one_line_exit_2(tmp_path, capsys):
    a = write_mimo(tmp_path / "a.yaml", rotated_block_diagonal(EQ18, ([100.0], [2.0, 1.0])))
    b = tmp_path / "b.yaml"
    b.write_text(open(P2).read().replace("pitch", "lateral"))
    assert main(["compare-models", a, str(b)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "2x2 model" in err and "1x1" in err


def test_simulate_and_replay_of_a_mimo_lateral_channel(tmp_path, capsys):
    """Issue 14 end to end: the simulator flies aileron then rudder sweeps whose truth is the full
    lateral-directional state space; the replay validates the 2 x 2 matrix: the model that flew is not
    model-limited (nu-gap < 0.15), the same model with 0.6 x aileron effectiveness is, with the aileron column
    named."""
    import yaml
    from test_mimo import LATERAL

    truth = tmp_path / "lateral.yaml"
    truth.write_text(yaml.safe_dump({"channels": {"lateral": LATERAL}}))
    weak = copy.deepcopy(LATERAL)
    weak["model"]["state_space"]["B"] = [
        [0.6 * row[0], row[1]] for row in LATERAL["model"]["state_space"]["B"]
    ]
    weaker = tmp_path / "weak.yaml"
    weaker.write_text(yaml.safe_dump({"channels": {"lateral": weak}}))
    bag = tmp_path / "flight"
    assert (
        main(
            [
                "simulate",
                "--config",
                str(truth),
                "--out",
                str(bag),
                "--sweeps",
                "2",
                "--sweep-duration",
                "40",
                "--sweep-gap-s",
                "3",
                "--seed",
                "3",
            ]
        )
        == 0
    )
    assert "lateral: 4 chirp manoeuvres (each input in turn)" in capsys.readouterr().out
    results = {}
    for name, config in (("truth", truth), ("weak", weaker)):
        out = tmp_path / f"{name}.json"
        assert main(["replay", str(bag), "--config", str(config), "--json", str(out), "--no-history",
                     "--no-progress"]) == 0
        results[name] = json.loads(out.read_text())["channels"]["lateral"]
        assert "lateral" in capsys.readouterr().out
    assert results["truth"]["nu_gap"] < 0.15 and results["truth"]["limited_by"] != "model"
    assert results["weak"]["limited_by"] == "model"
    assert results["weak"]["mimo"]["worst_elements"][0]["input"].endswith("position[aileron]")
    assert results["weak"]["diagnosis"][0]["parameters"]["input_index"] == 0
    # --apply-diagnosis does not write effects a MIMO model cannot take: it says what to change, in one line
    fixed = tmp_path / "fixed.yaml"
    assert main(["replay", str(bag), "--config", str(weaker), "--no-history", "--no-progress",
                 "--apply-diagnosis", str(fixed)]) == 0
    err = capsys.readouterr().err
    assert "lateral: not applied (a MIMO model takes no effects yet" in err and "gain 1.6" in err
    assert not fixed.exists()
