"""`shellsim sweep` on the shipped LEGO: one directory per combination, an index, a contact sheet whose cells
are the stills, a second run that redoes nothing, and the same PNGs bit for bit from Ray tasks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from shellsim.cli.main import main
from shellsim.viz.contact_sheet import LABEL_HEIGHT

ARGS = [
    "--asset",
    "lego",
    "--material",
    "rubber,jelly",
    "--drop-height",
    "0.1",
    "--frames",
    "2",
    "--size",
    "16x16",
]


@pytest.mark.slow
def test_sweep_writes_each_combination_an_index_and_a_contact_sheet_and_resumes(tmp_path):
    out = tmp_path / "sweep"
    assert main(["sweep", *ARGS, "--wind", "0.1", "--out", str(out)]) == 0
    index = json.loads((out / "index.json").read_text())
    names = [e["name"] for e in index["combinations"]]
    assert names == ["rubber_h0.1", "jelly_h0.1", "wind_0.1"]
    for entry in index["combinations"]:
        assert (out / entry["motion"]).is_file()
        assert sorted(p.name for p in (out / entry["frames"]).glob("*.png")) == ["00000.png", "00001.png"]
        assert entry["render"]["rendered"] == 2
    sheet = np.asarray(Image.open(out / "contact_sheet.png").convert("RGB"))
    assert sheet.shape == (2 * (16 + LABEL_HEIGHT), 2 * 16, 3)  # 3 stills: 2 columns, 2 rows
    for n, entry in enumerate(index["combinations"]):
        row, col = divmod(n, 2)
        cell = sheet[row * (16 + LABEL_HEIGHT) :][:16, col * 16 :][:, :16]
        assert np.array_equal(cell, np.asarray(Image.open(out / entry["still"]).convert("RGB")))
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*.png") if p.name != "contact_sheet.png"}

    assert main(["sweep", *ARGS, "--wind", "0.1", "--out", str(out)]) == 0  # finished: nothing redone
    again = json.loads((out / "index.json").read_text())
    assert [e["render"]["rendered"] for e in again["combinations"]] == [0, 0, 0]
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps


@pytest.mark.slow
def test_ray_sweep_makes_the_same_pngs(tmp_path):
    assert main(["sweep", *ARGS, "--out", str(tmp_path / "serial")]) == 0
    assert main(["sweep", *ARGS, "--out", str(tmp_path / "ray"), "--ray"]) == 0
    serial = sorted(p.relative_to(tmp_path / "serial") for p in (tmp_path / "serial").rglob("*.png"))
    assert serial == sorted(p.relative_to(tmp_path / "ray") for p in (tmp_path / "ray").rglob("*.png"))
    for rel in serial:
        assert (tmp_path / "serial" / rel).read_bytes() == (tmp_path / "ray" / rel).read_bytes(), rel


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--material", "rubber,cheese"], "--material: unknown material 'cheese'"),
        (["--drop-height", "0.1,-1"], "--drop-height: expected a height in metres in [0, 100], got -1"),
        (["--wind", "0.1,x"], "--wind: expected comma-separated numbers, got '0.1,x'"),
        (["--material", "rubber,rubber"], "--material: each value may be given once"),
    ],
)
def test_bad_values_are_one_line_before_any_work(tmp_path, capsys, extra, message):
    assert main(["sweep", "--asset", "lego", "--out", str(tmp_path / "s"), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"shellsim: error: {message}") and err.count("\n") == 1
    assert not (tmp_path / "s").exists()
