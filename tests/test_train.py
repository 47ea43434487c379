"""Training stages 1 and 2 on a scene the test renders itself, checkpoints/resume, and CLI errors."""

from __future__ import annotations

import dataclasses
import json
import types

import numpy as np
import pytest
import torch
import trimesh
from scenes import write_sphere_scene

from neural.config import NarrowBandConfig
from neural.data import load_dataset
from neural.field import FieldConfig, HashGridConfig, ShellField
from neural.pipeline import build_field
from neural.render.view import field_occupancy_grid, occupancy_sampler
from neural.train import (
    GRID_PARAMETERS,
    PixelSampler,
    Stage1Config,
    Stage2Config,
    evaluate,
    regularisers,
    train_stage1,
    train_stage2,
)
from shellsim.cli.main import main

SMALL_FIELD = FieldConfig(hashgrid=HashGridConfig(log2_table_size=14, max_resolution=256))


def small_stage1(steps: int) -> Stage1Config:
    return Stage1Config(
        steps=steps,
        target_samples=8192,
        initial_rays=256,
        eval_every=10**6,
        checkpoint_every=20,
        occupancy_resolution=32,
        warmup_steps=20,
        eval_views=3,
    )


@pytest.fixture(scope="module")
def sphere_data(tmp_path_factory):
    root = write_sphere_scene(tmp_path_factory.mktemp("sphere"), n_views=24, size=32)
    return load_dataset(root, bound=1.0)


def test_random_background_only_behind_empty_pixels(sphere_data):
    # straight colour c with coverage a per pixel (0 on the left half, 0.3 or 1 on the right), stored
    # composited on white as the loader does
    c = np.array([0.2, 0.5, 0.9], np.float32)
    white = np.ones(3, np.float32)
    n, h, w = sphere_data.images.shape[:3]
    alphas = np.zeros((n, h, w), np.float32)
    alphas[:, : h // 2, w // 2 :] = 0.3
    alphas[:, h // 2 :, w // 2 :] = 1.0
    stored = c * alphas[..., None] + white * (1 - alphas[..., None])
    data = dataclasses.replace(sphere_data, images=stored, alphas=alphas, background=white)
    _, _, rgb, background = PixelSampler(data, "cpu", seed=3, random_background=True).sample(4096)
    # the same seed draws the same pixels: their stored colours tell empty, edge and solid pixels apart
    _, _, stored_rgb, _ = PixelSampler(data, "cpu", seed=3, random_background=False).sample(4096)
    white_t = torch.as_tensor(white)
    kinds = {
        a: (stored_rgb - torch.as_tensor(c * a + white * (1 - a))).abs().max(1).values < 1e-6
        for a in (0, 0.3, 1)
    }
    assert all(m.sum() > 500 for m in kinds.values()) and sum(m.long() for m in kinds.values()).eq(1).all()
    empty, covered = kinds[0], ~kinds[0]
    assert background.shape == (4096, 3) and 0 <= background.min() and background.max() <= 1
    assert background[empty].std(0).min() > 0.25  # uniform on [0, 1]: std 0.289
    torch.testing.assert_close(rgb[empty], background[empty])  # nothing in front: the new colour itself
    torch.testing.assert_close(background[covered], white_t.expand(int(covered.sum()), 3))
    torch.testing.assert_close(rgb[covered], stored_rgb[covered])  # edges and solids keep their composite

    opaque = dataclasses.replace(data, alphas=None)
    _, _, rgb, background = PixelSampler(opaque, "cpu", seed=3, random_background=True).sample(4096)
    assert background.shape == (3,)  # without alpha the images' own background is the truth
    torch.testing.assert_close(rgb, stored_rgb)


def test_error_sampling_draws_tiles_in_proportion_to_their_error(sphere_data):
    """Closed form: a tile with error e is drawn with probability e / sum(errors); the pixel is uniform inside
    it, also in the tiles cut by the image's edge (32 pixels in tiles of 12: 12, 12, 8)."""
    pixels = PixelSampler(sphere_data, "cpu", seed=5, error_sampling=1.0, tile=12)
    assert pixels.tiles == (3, 3)
    errors = torch.full_like(pixels.errors, 0.01)
    view_2 = 2 * 9
    errors[view_2 + 8] = 0.5  # the corner tile of the third view: rows and columns 24-31
    errors[view_2 + 4] = 0.25  # its centre tile: rows and columns 12-23
    pixels.errors = errors.clone()
    n = 40000
    k, py, px = pixels._by_error(n)
    tiles = (k * 3 + py // 12) * 3 + px // 12
    counts = torch.bincount(tiles, minlength=len(errors)).double()
    expected = n * errors.double() / errors.sum()
    assert ((counts - expected).abs() <= 5 * expected.sqrt() + 1).all()  # within 5 sigma of a Poisson count
    corner = (k == 2) & (py >= 24) & (px >= 24)
    assert corner.sum() == counts[view_2 + 8] and py.max() == 31 and px.max() == 31
    in_corner = torch.stack([py[corner], px[corner]], 1) - 24
    assert torch.bincount(in_corner[:, 0] * 8 + in_corner[:, 1], minlength=64).min() > 0  # all 8x8 pixels
    origins, dirs, rgb, _ = pixels.sample(1000)
    assert len(pixels.drawn) == len(origins) == len(rgb) == 1000 and torch.isfinite(dirs).all()


def test_error_map_keeps_the_running_mean_of_each_tile(sphere_data):
    """record() folds the squared colour errors of the rays last drawn into (old + sum) / (1 + count) per
    tile (a slow loop is the reference); uniform draws record too, and a map of other tiles is not
    restored."""
    pixels = PixelSampler(sphere_data, "cpu", seed=9, error_sampling=0.5, tile=8)
    before = pixels.errors.clone()
    pixels.sample(3000)
    drawn = pixels.drawn.clone()
    colors, targets = torch.rand((2, 3000, 3), generator=torch.Generator().manual_seed(1))
    pixels.record(colors, targets)
    squared = ((colors - targets) ** 2).mean(1)  # each ray's squared error, the mean over its channels
    expected = before.clone()
    for tile in drawn.unique().tolist():
        mine = squared[drawn == tile]
        expected[tile] = (before[tile] + mine.sum()) / (1 + len(mine))
    torch.testing.assert_close(pixels.errors, expected)
    restored = PixelSampler(sphere_data, "cpu", seed=0, error_sampling=0.5, tile=8)
    restored.load_state(pixels.state())
    assert torch.equal(restored.errors, pixels.errors)
    other = PixelSampler(sphere_data, "cpu", seed=0, error_sampling=0.5, tile=16)
    other.load_state(pixels.state())
    assert other.errors.eq(1).all()
    uniform = PixelSampler(sphere_data, "cpu", seed=9)
    assert uniform.state() == {}


def test_the_same_command_trains_the_same_field(sphere_data, tmp_path):
    """The initial weights come from the seed, not from torch's global generator (which is left as it
    was), and training from them is deterministic: two runs give bit-identical fields."""
    state = torch.random.get_rng_state()
    first, second = (build_field(sphere_data, SMALL_FIELD, "cpu") for _ in range(2))
    assert torch.equal(torch.random.get_rng_state(), state)
    other = build_field(sphere_data, SMALL_FIELD, "cpu", seed=1)
    assert not torch.equal(other.encoding.table, first.encoding.table)
    for k, field in enumerate((first, second)):
        torch.rand(7)  # training reseeds: what drew from the global generator before does not matter
        train_stage1(field, sphere_data, tmp_path / str(k), small_stage1(6), "cpu")
    trained = second.state_dict()
    for key, value in first.state_dict().items():
        assert torch.equal(value, trained[key]), key


@pytest.mark.slow  # about a minute on 2 cores
def test_stage1_improves_psnr_on_a_rendered_sphere(sphere_data, tmp_path):
    torch.manual_seed(0)
    field = build_field(sphere_data, SMALL_FIELD, "cpu")
    config = small_stage1(150)
    grid = field_occupancy_grid(field, config.occupancy_resolution)
    background = torch.ones(3)
    before = evaluate(field, sphere_data, sphere_data.test_idx, occupancy_sampler(grid, field), background)
    result = train_stage1(field, sphere_data, tmp_path, config, "cpu")
    after = result["final"]
    assert after["views"] == [int(v) for v in sphere_data.test_idx[:3]]
    assert after["psnr"] > before["psnr"] + 4.0, (before["psnr"], after["psnr"])


@pytest.mark.slow
def test_stage1_resumes_from_its_checkpoint(sphere_data, tmp_path):
    field = build_field(sphere_data, SMALL_FIELD, "cpu")
    train_stage1(field, sphere_data, tmp_path, small_stage1(20), "cpu")
    weights = {k: v.clone() for k, v in field.state_dict().items()}
    resumed = build_field(sphere_data, SMALL_FIELD, "cpu")
    result = train_stage1(resumed, sphere_data, tmp_path, small_stage1(20), "cpu")
    # nothing left to do: the checkpoint's weights and final evaluation come back as they were
    for key, value in resumed.state_dict().items():
        torch.testing.assert_close(value, weights[key], rtol=0, atol=0)
    assert result["final"] is not None and result["final"]["step"] == 20
    longer = train_stage1(resumed, sphere_data, tmp_path, small_stage1(30), "cpu")
    # one curve over both runs: the first run's evaluation stays, and the clock goes on from its time
    assert [h["step"] for h in longer["history"]] == [20, 30]
    assert 0 < longer["history"][0]["train_seconds"] < longer["history"][1]["train_seconds"]


def _run_cli(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


def test_train_cli_reports_bad_inputs_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "transforms_train.json").write_text("{not json")
    code, err = _run_cli(["train", "--data", str(bad), "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and err.count("\n") == 0 and "transforms_train.json" in err

    missing = write_sphere_scene(tmp_path / "missing", n_views=3, size=8)
    for png in (missing / "train").glob("*.png"):
        png.unlink()
    code, err = _run_cli(["train", "--data", str(missing), "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and err.count("\n") == 0 and "image" in err

    nokey = tmp_path / "nokey"
    nokey.mkdir()
    (nokey / "transforms_train.json").write_text(json.dumps({"frames": []}))
    code, err = _run_cli(["train", "--data", str(nokey), "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and err.count("\n") == 0 and ("camera_angle_x" in err or "frames" in err)

    code, err = _run_cli(
        ["train", "--data", str(missing), "--out", str(tmp_path / "o"), "--steps", "0"], capsys
    )
    assert code == 2 and "--steps" in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_train_cli_keeps_a_finished_asset(tmp_path, capsys):
    data = write_sphere_scene(tmp_path / "data", n_views=3, size=8)
    done = tmp_path / "asset"
    done.mkdir()
    (done / "asset.json").write_text("{}")
    code, err = _run_cli(["train", "--data", str(data), "--out", str(done)], capsys)
    assert code == 2 and "finished asset" in err and (done / "asset.json").read_text() == "{}"


def _failing_sampler(monkeypatch, at_call: int, error: BaseException):
    """Make the pixel sampler raise ``error`` on its ``at_call``-th call (a crash or Ctrl-C mid-stage)."""
    original, calls = PixelSampler.sample, []

    def sample(self, n):
        calls.append(n)
        if len(calls) == at_call:
            raise error
        return original(self, n)

    monkeypatch.setattr(PixelSampler, "sample", sample)


def test_stage1_checkpoints_by_time_and_on_interrupt(sphere_data, tmp_path, monkeypatch):
    """Checkpoints by time and on Ctrl-C; on any exception the progress bar is closed first (else tqdm prints
    it again at exit, after the CLI's one-line error)."""
    import neural.train
    from neural.checkpoint import load_checkpoint

    bars = []
    progress = neural.train._progress
    monkeypatch.setattr(neural.train, "_progress", lambda *a: bars.append(progress(*a)) or bars[-1])
    ckpt = tmp_path / "checkpoints" / "stage1.safetensors"
    config = dataclasses.replace(small_stage1(40), checkpoint_every=10**6, checkpoint_seconds=0.0)
    _failing_sampler(monkeypatch, 7, RuntimeError("killed"))  # no handler runs: only what is on disk counts
    with pytest.raises(RuntimeError):
        train_stage1(build_field(sphere_data, SMALL_FIELD, "cpu"), sphere_data, tmp_path, config, "cpu")
    assert len(bars) == 1 and bars[0].n == 6 and bars[0].disable  # tqdm.close() disables the bar
    field = build_field(sphere_data, SMALL_FIELD, "cpu")
    assert load_checkpoint(ckpt, field)[0]["step"] == 6  # by time: every step when checkpoint_seconds is 0

    config = dataclasses.replace(config, checkpoint_seconds=1e9)  # neither by steps nor by time...
    _failing_sampler(monkeypatch, 4, KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        train_stage1(field, sphere_data, tmp_path, config, "cpu")
    assert load_checkpoint(ckpt, build_field(sphere_data, SMALL_FIELD, "cpu"))[0]["step"] == 9  # ...on Ctrl-C
    assert len(bars) == 2 and bars[1].disable


def test_a_short_run_scales_stage2_and_the_grids_with_its_steps(tmp_path, monkeypatch, capsys):
    """--steps 200 (a first try) must not run the default 1000 stage-2 steps nor the 256^3 extraction;
    explicit options win; --help says so."""
    import neural.pipeline

    configs = []
    monkeypatch.setattr(
        neural.pipeline, "train_asset", lambda data, out, config, *a, **k: configs.append(config) or out
    )
    trained = types.SimpleNamespace(meta={"training": {"wall_minutes": 0.0}})  # what the job reports
    monkeypatch.setattr("neural.asset.load_asset", lambda root: trained)
    base = ["train", "--data", str(tmp_path), "--out", str(tmp_path / "out")]
    assert main([*base, "--steps", "200", "--checkpoint-minutes", "0.5"]) == 0
    assert main([*base, "--steps", "200", "--stage2-steps", "7", "--shell-resolution", "64"]) == 0
    assert main(base) == 0
    quick, explicit, default = configs
    assert quick.stage2.steps <= 200 // 5 and quick.shell.resolution <= 128
    assert quick.stage1.target_samples <= default.stage1.target_samples // 4
    assert quick.stage1.checkpoint_seconds == quick.stage2.checkpoint_seconds == 30.0
    assert (explicit.stage2.steps, explicit.shell.resolution) == (7, 64)
    assert (default.stage1.steps, default.stage2.steps, default.shell.resolution) == (6000, 1000, 256)
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    assert "--steps / 6" in capsys.readouterr().out


def test_sharpness_prior_is_the_log_kernel_excess_over_its_floor():
    """mean(relu(log(s / s_floor))) with s_floor = sharp_floor * step_size in unit space (world: / scale):
    closed form on chosen kernels, and zero gradient for kernels already below the floor."""
    field = ShellField(SMALL_FIELD, scale=0.5)
    config = Stage1Config()
    floor = config.sharp_floor * config.step_size / 0.5  # world units
    s = torch.tensor([floor * 4.0, floor * 0.5, floor * 2.0], requires_grad=True)
    points = torch.zeros(3, 3)
    normals = torch.nn.functional.normalize(torch.ones(3, 3), dim=1)
    reg = regularisers(field, points, normals, 1.0 / s, config, torch.Generator().manual_seed(0))
    assert float(reg["sharp"].detach()) == pytest.approx((np.log(4.0) + np.log(2.0)) / 3, rel=1e-5)
    (grad,) = torch.autograd.grad(reg["sharp"], s)
    np.testing.assert_allclose(grad.numpy(), [1 / (3 * floor * 4.0), 0.0, 1 / (3 * floor * 2.0)], rtol=1e-4)


def test_stage2_ramps_its_rates_up_from_the_fresh_optimiser(sphere_data, tmp_path):
    """Adam's first update of a parameter is ``lr * g / (|g| + eps)``, at most ``lr`` in size: with a warm-up
    of W steps, stage 2's first step moves no weight by more than its group's base rate / W (at the full rate
    it would throw the stage-1 field off), and each group's largest move reaches that bound."""
    field = build_field(sphere_data, SMALL_FIELD, "cpu")
    before = {k: p.detach().clone() for k, p in field.named_parameters()}
    outer, inner = trimesh.creation.icosphere(3, 0.75), trimesh.creation.icosphere(3, 0.45)
    config = Stage2Config(steps=1, rays=512, warmup_steps=8, eval_views=1, checkpoint_every=10**6)
    train_stage2(field, sphere_data, outer, inner, tmp_path, config, NarrowBandConfig(), "cpu")
    moves = {k: float((p.detach() - before[k]).abs().max()) for k, p in field.named_parameters()}
    grids = max(v for k, v in moves.items() if k.startswith(GRID_PARAMETERS))
    networks = max(v for k, v in moves.items() if not k.startswith(GRID_PARAMETERS))
    for move, rate in ((grids, config.lr_encoding), (networks, config.lr_network)):
        assert rate / 8 * 0.99 <= move <= rate / 8 + 1e-6, (moves, rate)  # 1e-6: float32 rounding near 1


def test_learning_rate_warms_up_from_the_optimizers_first_step_and_decays_over_the_schedule():
    """A fresh optimizer at step 12000 of an 18000-step schedule (a continued training): warm-up over 100
    steps from there, times 0.1 ** (step / 18000)."""
    from neural.train import set_learning_rate

    param = torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.Adam([{"params": [param], "lr": 1.0, "base_lr": 3e-2}])
    for step, warm in ((12000, 1 / 100), (12049, 50 / 100), (12099, 1.0), (17999, 1.0)):
        set_learning_rate(optimizer, step, 18000, 100, 0.1, fresh_at=12000)
        assert optimizer.param_groups[0]["lr"] == pytest.approx(3e-2 * warm * 0.1 ** (step / 18000))
    set_learning_rate(optimizer, 0, 18000, 100, 0.1)  # a fresh training: from step 0
    assert optimizer.param_groups[0]["lr"] == pytest.approx(3e-2 / 100)
