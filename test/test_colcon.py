"""The package builds with colcon (ament_python) and installs both console scripts where ``ros2 run``
looks."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _colcon() -> str | None:
    here = Path(sys.executable).parent / "colcon"
    return str(here) if here.exists() else shutil.which("colcon")


def _package_files() -> list[str]:
    """Files of the package as git sees them (tracked and new, not ignored); bags are not needed to build."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.split("\n")
        files = [f for f in out if f and not f.startswith("bags/")]
    except (OSError, subprocess.CalledProcessError):
        files = []
    if not files:  # not a git checkout: the files a build needs
        files = [str(p.relative_to(ROOT)) for d in ("gap_validation", "config", "launch", "resource")
                 for p in (ROOT / d).rglob("*") if p.is_file() and "__pycache__" not in p.parts]
        files += ["setup.py", "setup.cfg", "package.xml"]
    return [f for f in files if (ROOT / f).is_file()]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    colcon = _colcon()
    if colcon is None:
        pytest.skip("colcon is not installed (pip install colcon-common-extensions)")
    ws = tmp_path_factory.mktemp("ws")
    src = ws / "src" / "gap_validation"
    for name in _package_files():
        target = src / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, target)
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    proc = subprocess.run([colcon, "build", "--event-handlers", "console_direct-"], cwd=ws, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"colcon build failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return ws, env


def test_colcon_build_installs_console_scripts_launch_and_params(built):
    ws, _ = built
    prefix = ws / "install" / "gap_validation"
    for script in ("validator_node", "gap-validate"):
        path = prefix / "lib" / "gap_validation" / script
        assert path.is_file(), f"{path} missing"
        assert os.access(path, os.X_OK)
    share = prefix / "share" / "gap_validation"
    assert (share / "launch" / "validator.launch.py").is_file()
    assert (share / "config" / "validator.params.yaml").is_file()
    assert (share / "package.xml").is_file()
    assert (
        ws / "install" / "share" / "ament_index" / "resource_index" / "packages" / "gap_validation"
    ).exists() or (share.parent / "ament_index" / "resource_index" / "packages" / "gap_validation").exists()


def test_installed_validator_node_runs_and_rejects_a_missing_config(built, tmp_path):
    ws, env = built
    prefix = ws / "install" / "gap_validation"
    site = next(prefix.glob("lib/python*/site-packages"))
    env = dict(env, PYTHONPATH=f"{site}{os.pathsep}{env.get('PYTHONPATH', '')}")
    script = prefix / "lib" / "gap_validation" / "validator_node"
    missing = tmp_path / "missing.yaml"
    proc = subprocess.run([sys.executable, str(script), "--ros-args", "-p", f"config_file:={missing}"],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == [f"validator_node: error: {missing}: config file not found"], proc.stderr
    helped = subprocess.run([sys.executable, str(script), "--help"], env=env, capture_output=True, text=True,
                            timeout=120)
    assert helped.returncode == 0 and "config_file" in helped.stdout
