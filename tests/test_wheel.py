"""The built wheel works without the source tree: shipped assets are package data, nothing is written into
the installed package, and the README's main command runs from another directory (about a minute)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_installs_and_simulates_the_shipped_asset_outside_the_repository(tmp_path):
    wheels, site, work = tmp_path / "wheels", tmp_path / "site", tmp_path / "work"
    work.mkdir()
    pip = [sys.executable, "-m", "pip", "-q", "--disable-pip-version-check"]
    subprocess.run(
        [*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(ROOT)], check=True
    )
    (wheel,) = wheels.glob("shellsim-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True)
    env = {**os.environ, "PYTHONPATH": str(site), "SHELLSIM_CACHE": str(tmp_path / "cache")}
    env.pop("SHELLSIM_ASSETS", None)
    where = subprocess.run(
        [
            sys.executable,
            "-c",
            "import shellsim, neural.asset as a; print(shellsim.__file__, a.shipped_assets_dir())",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert all(Path(p).is_relative_to(site) for p in where), where
    lego = Path(where[1]) / "lego"
    before = {p.name: p.stat().st_mtime_ns for p in lego.iterdir()}
    assert {"asset.json", "field.safetensors", "shell_outer.ply", "shell_inner.ply", "cage.npz"} <= set(
        before
    )
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "shellsim.cli.main",
            "simulate",
            "--asset",
            "lego",
            "--material",
            "rubber",
            "--frames",
            "2",
            "--out",
            "drop.npz",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert (work / "drop.npz").is_file()
    assert {p.name: p.stat().st_mtime_ns for p in lego.iterdir()} == before
    assert not (tmp_path / "cache").exists()  # the shipped cage was used as it is
