"""Scene contraction (neural.field.contraction) against closed forms: Mip-NeRF 360's map and its inverse,
its Jacobian against central differences in float64, and the lengths it gives along and across the radius."""

from __future__ import annotations

import torch

from neural.field.contraction import contract, contract_jacobian, contracted_length, uncontract


def points(n: int = 400, seed: int = 0) -> torch.Tensor:
    """(n, 3) float64 points at radii spread from 0.01 to 1000 in random directions."""
    g = torch.Generator().manual_seed(seed)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1)
    return dirs * torch.logspace(-2, 3, n, dtype=torch.float64)[:, None]


def test_the_unit_ball_stays_and_everything_else_lands_inside_radius_two():
    x = points()
    y = contract(x)
    r = x.norm(dim=1)
    torch.testing.assert_close(y[r <= 1], x[r <= 1], rtol=0, atol=0)
    torch.testing.assert_close(y.norm(dim=1)[r > 1], 2 - 1 / r[r > 1])  # |y| = 2 - 1/|x|
    torch.testing.assert_close(
        torch.nn.functional.normalize(y, dim=1), torch.nn.functional.normalize(x, dim=1)
    )
    assert (y.norm(dim=1) < 2).all()


def test_uncontract_inverts_contract():
    x = points()
    torch.testing.assert_close(uncontract(contract(x)), x, rtol=1e-9, atol=1e-12)


def test_the_jacobian_matches_central_differences():
    x = points(200, seed=1)
    eps = 1e-6 * x.norm(dim=1, keepdim=True).clamp_min(1.0)
    columns = [
        (contract(x + eps * e) - contract(x - eps * e)) / (2 * eps) for e in torch.eye(3, dtype=x.dtype)
    ]
    numeric = torch.stack(columns, dim=2)
    torch.testing.assert_close(contract_jacobian(x), numeric, rtol=1e-6, atol=1e-9)


def test_lengths_along_and_across_the_radius():
    """A unit length along the radius at r > 1 becomes 1 / r^2 (d|y|/dr of 2 - 1/r); across it, the
    sphere of radius r is mapped onto the one of radius 2 - 1/r, so lengths scale by (2 - 1/r) / r."""
    x = points(300, seed=2)
    r = x.norm(dim=1)
    radial = x / r[:, None]
    across = torch.nn.functional.normalize(
        torch.linalg.cross(x, torch.tensor([[0.3, -0.5, 0.8]], dtype=x.dtype).expand_as(x)), dim=1
    )
    out = r > 1
    torch.testing.assert_close(contracted_length(x, radial)[out], 1 / r[out] ** 2)
    torch.testing.assert_close(contracted_length(x, across)[out], (2 - 1 / r[out]) / r[out])
    torch.testing.assert_close(contracted_length(x, radial)[~out], torch.ones_like(r[~out]))


def test_a_field_in_contracted_space_lets_through_what_brute_force_says():
    """A sphere living in contracted space, beyond the unit ball (world distance about 6), seen along world
    rays sampled in world steps and carried by ContractionMap: the pipeline's transmittance against a
    brute-force march of the exact contracted SDF along the ray, ``T = prod max(Phi(s f_k+1) / Phi(s f_k),
    ...)`` with NeuS's discrete opacity over 200,000 world steps."""
    from scenes import SphereField
    from test_ground import stepped_sampler

    from neural.field.contraction import ContractionMap
    from neural.render.view import transmittance

    far = torch.tensor([[6.0, 1.0, 0.5]], dtype=torch.float64)
    centre = contract(far)[0]
    field = SphereField(radius=0.1, inv_s=200.0, center=tuple(centre.tolist()))
    target = uncontract(centre[None] + torch.tensor([[0.0, 0.05, 0.0]], dtype=torch.float64))  # through it
    origins = torch.zeros(3, 3, dtype=torch.float64)
    origins[1, 2], origins[2, 1] = 0.4, -0.3
    ends = torch.cat([target, target, far + torch.tensor([[0.0, 4.0, 0.0]], dtype=torch.float64)])
    dirs = torch.nn.functional.normalize(ends - origins, dim=1)
    got = transmittance(field, origins.float(), dirs.float(), stepped_sampler(2e-3, 40.0), ContractionMap())
    t = torch.linspace(0.0, 40.0, 200001, dtype=torch.float64)
    expected = []
    for o, d in zip(origins, dirs, strict=True):
        y = contract(o + t[:, None] * d)
        phi = torch.sigmoid(200.0 * ((y - centre).norm(dim=1) - 0.1))
        alpha = ((phi[:-1] - phi[1:]) / phi[:-1]).clamp(0.0, 1.0)
        expected.append(torch.prod(1.0 - alpha))
    expected = torch.stack(expected)
    assert expected[0] < 0.01 and expected[2] > 0.99  # through the sphere; past it
    torch.testing.assert_close(got.double(), expected, rtol=0, atol=2e-3)


def _field(scale: float = 0.5, center=(0.2, -0.1, 0.3)):
    from neural.config import FieldConfig, HashGridConfig
    from neural.field import ShellField

    config = FieldConfig(
        hashgrid=HashGridConfig(n_levels=2, log2_table_size=8, max_resolution=32), contract=True
    )
    return ShellField(config, center=center, scale=scale)


def test_contracted_steps_cover_the_ray_to_far_away_at_the_step_length():
    from neural.render.occupancy import FAR_RADIUS
    from neural.render.view import field_occupancy_grid, occupancy_sampler

    field = _field()
    radius = field.contraction.radius
    assert radius == 1.0  # the object's unit ball: half the box, whose half-side is 1 / scale = 2
    grid = field_occupancy_grid(field, 16)  # never probed: every cell counts as occupied
    g = torch.Generator().manual_seed(3)
    origins = field.center + torch.nn.functional.normalize(torch.randn(64, 3, generator=g), dim=1) * 2.5
    dirs = torch.nn.functional.normalize(
        field.center + 0.7 * torch.randn(64, 3, generator=g) - origins, dim=1
    )
    step = 0.01
    samples = occupancy_sampler(grid, field, step * float(field.scale), max_samples=4096, perturb=True)(
        origins, dirs
    )
    o, d = origins.double(), dirs.double()
    ray = samples.ray_indices

    def contracted(t):  # (S, 3) contracted points, ball units
        return contract((o[ray] + t.double()[:, None] * d[ray] - field.center.double()) / radius)

    lengths = (contracted(samples.t_ends) - contracted(samples.t_starts)).norm(dim=1)
    # arcs of one step, measured by chords (the last sections, beyond the far end's node, a little longer)
    assert abs(lengths.median() / step - 1) < 0.05
    assert lengths.quantile(0.99) < 1.1 * step and lengths.max() < 1.3 * step
    same = ray[1:] == ray[:-1]
    gaps = (samples.t_starts[1:] - samples.t_ends[:-1])[same] / samples.deltas[1:][same]
    assert gaps.abs().max() < 0.05  # consecutive sections meet (relative to their length)
    first = torch.ones_like(ray, dtype=torch.bool)
    first[1:] = ~same
    at_origin = contracted(torch.zeros_like(samples.t_starts))
    assert ((contracted(samples.t_starts) - at_origin).norm(dim=1)[first] < step).all()  # from the camera on
    last = torch.ones_like(ray, dtype=torch.bool)
    last[:-1] = ~same
    reach = contracted(samples.t_ends).norm(dim=1)[last]
    assert (reach > 2 - 1 / FAR_RADIUS - 2 * step).all()  # out to the far end of the contracted ball


def test_a_contracted_asset_loads_with_its_contraction(tmp_path):
    import trimesh

    from neural.asset import load_asset, load_field, save_asset

    field = _field()
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    normalisation = {"center": [0.2, -0.1, 0.3], "scale": 1.0}  # the object's box: 1 / scale = 1 each side
    save_asset(tmp_path, field, ball, ball, {"name": "room", "normalisation": normalisation})
    asset = load_asset(tmp_path)
    loaded = load_field(asset)
    assert loaded.contraction.radius == field.contraction.radius
    assert asset.contraction.radius == field.contraction.radius  # what its narrow band counts widths by
    torch.testing.assert_close(asset.contraction.center, field.contraction.center.double())
    x = torch.randn(50, 3, generator=torch.Generator().manual_seed(0)) * 5
    d = torch.nn.functional.normalize(torch.randn(50, 3), dim=1)
    torch.testing.assert_close(loaded.contraction.map_rays(x, d)[0], field.contraction.map_rays(x, d)[0])
    torch.testing.assert_close(
        loaded.contraction.to_world(loaded.contraction.to_field(x)), x, atol=1e-4, rtol=1e-4
    )


def test_narrow_band_intervals_far_out_are_counted_by_their_contracted_width():
    """Along a radius, ``contract`` maps ``r > 1`` to ``2 - 1 / r``: a shell between radii 3 and 4 (world
    width 1) is 1/12 wide in contracted space and gets the samples of that width, not of 1."""
    import numpy as np
    import trimesh

    from neural.config import NarrowBandConfig
    from neural.field.contraction import ContractionMap
    from neural.render.narrowband import narrow_band_samples
    from neural.render.raycast import EmbreeCaster

    caster = EmbreeCaster(
        trimesh.creation.icosphere(subdivisions=4, radius=4.0),
        trimesh.creation.icosphere(subdivisions=4, radius=3.0),
    )
    config = NarrowBandConfig(delta_s=0.01, w_s=0.0, n_max=64, max_peel=4)
    origins, dirs = np.array([[-10.0, 0.0, 0.0]]), np.array([[2.0, 0.0, 0.0]])
    _, world = narrow_band_samples(caster, origins, dirs, config)
    _, contracted = narrow_band_samples(caster, origins, dirs, config, contraction=ContractionMap())
    assert world.counts.tolist() == [64]
    r_enter, r_exit = (10.0 - 2.0 * t for t in (contracted.interval_enter[0], contracted.interval_exit[0]))
    assert 3.9 < r_enter < 4.001 and 2.9 < r_exit < 3.001
    width = (2.0 - 1.0 / r_enter) - (2.0 - 1.0 / r_exit)
    assert contracted.counts.tolist() == [int(np.ceil(width / 0.01)) + 1]
    assert contracted.counts[0] in (9, 10)
