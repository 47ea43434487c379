"""Hash encoding: the Warp kernels against the torch reference, and both against closed forms."""

import math

import pytest
import torch

from neural.field import HashGridConfig, HashGridEncoding, hash_encode_torch
from neural.field.hashgrid import is_dense
from neural.field.hashgrid_warp import CPU_BLOCK, _kernels, _launch, hash_encode_warp

# 4, 6, 12, 21, 36, 64 with T = 4096: three dense levels, three hashed levels with collisions
SMALL = HashGridConfig(n_levels=6, log2_table_size=12, base_resolution=4, max_resolution=64)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def py_row(vertex, resolution, table_size):
    """Table row of an integer grid vertex, in plain Python integers (uint32 hash)."""
    x, y, z = vertex
    if (resolution + 1) ** 3 <= table_size:
        return x + (resolution + 1) * (y + (resolution + 1) * z)
    return ((x * 1) ^ (y * 2654435761) ^ (z * 805459861)) % 2**32 % table_size


def random_points(n, generator):
    """(n, 3) points mostly inside [0,1]^3, some outside (clamped) and some exactly on the faces."""
    x = torch.rand(n, 3, generator=generator) * 1.2 - 0.1
    x[: n // 10, 0] = 1.0
    x[n // 10 : n // 5, 1] = 0.0
    return x


def test_resolutions_follow_the_geometric_growth():
    res = HashGridConfig().resolutions()
    assert len(res) == 14 and res[0] == 16 and res[-1] == 2048
    b = math.exp((math.log(2048) - math.log(16)) / 13)
    assert res == [math.floor(16 * b**level + 1e-6) for level in range(14)]
    paper = HashGridConfig(log2_table_size=22, max_resolution=4096).resolutions()
    assert paper[0] == 16 and paper[-1] == 4096 and all(a < b for a, b in zip(paper, paper[1:], strict=False))
    assert HashGridConfig(n_levels=1).resolutions() == [16]


def test_small_config_has_dense_and_colliding_hashed_levels():
    dense = [is_dense(r, SMALL.table_size) for r in SMALL.resolutions()]
    assert dense == [True, True, True, False, False, False]
    # hashed levels have more vertices than rows, so distinct vertices share rows (pigeonhole)
    assert all((r + 1) ** 3 > SMALL.table_size for r in SMALL.resolutions()[3:])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("n_points", [1, 7, 3000])
@pytest.mark.parametrize("cpu_threads", [1, 2])
def test_warp_matches_torch_in_values_and_table_gradients(device, n_points, cpu_threads):
    gen = torch.Generator().manual_seed(n_points)
    x = random_points(n_points, gen).to(device)
    table = torch.randn(SMALL.n_levels, SMALL.table_size, 2, generator=gen).to(device).requires_grad_()
    res = SMALL.resolutions()
    fast = hash_encode_warp(x, table, res, cpu_threads=cpu_threads)
    ref = hash_encode_torch(x, table, res)
    assert fast.shape == (n_points, SMALL.out_dim)
    torch.testing.assert_close(fast, ref, rtol=1e-5, atol=1e-5)
    upstream = torch.randn(fast.shape, generator=gen).to(device)
    (g_fast,) = torch.autograd.grad(fast, table, upstream)
    (g_ref,) = torch.autograd.grad(ref, table, upstream)
    torch.testing.assert_close(g_fast, g_ref, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("n_features", [1, 2, 4])
def test_cpu_block_kernel_gives_the_bits_of_the_per_point_kernel(n_features):
    """The CPU forward (a vectorised C++ loop over blocks of points) against the per-point Warp kernel that
    CUDA runs, level by level: the same float32 bits, across block boundaries, for points outside the cube,
    infinite or NaN (clamped into the cube, NaN to 0, as Warp's clamp does), on dense and hashed levels."""
    import warp as wp

    gen = torch.Generator().manual_seed(n_features)
    table = torch.randn(SMALL.n_levels, SMALL.table_size, n_features, generator=gen)
    res = SMALL.resolutions()
    vecf, per_point, _, per_block = _kernels(n_features)
    for n in (1, CPU_BLOCK - 1, CPU_BLOCK, CPU_BLOCK + 1, 3 * CPU_BLOCK + 17):
        x = random_points(n, gen)
        x[-3:] = torch.tensor([[math.nan, 0.5, 0.5], [math.inf, -math.inf, 0.5], [-0.0, 1.0, math.nan]])[-n:]
        outs = []
        for kernel, points_per_thread in ((per_point, 1), (per_block, CPU_BLOCK)):
            out = torch.full((n * SMALL.n_levels, n_features), math.nan)
            _launch(
                kernel,
                wp.from_torch(x, dtype=wp.vec3),
                wp.from_torch(table.view(-1, n_features), dtype=vecf),
                wp.from_torch(out, dtype=vecf),
                res,
                SMALL.table_size,
                cpu_threads=2,
                points_per_thread=points_per_thread,
            )
            outs.append(out)
        assert not outs[1].isnan().any()
        assert torch.equal(outs[0], outs[1]), n


def test_warp_points_without_gradient_and_empty_input():
    table = torch.zeros(SMALL.n_levels, SMALL.table_size, 2, requires_grad=True)
    x = torch.rand(5, 3, requires_grad=True)
    out = hash_encode_warp(x, table, SMALL.resolutions())
    out.sum().backward()
    assert x.grad is None and table.grad is not None  # documented: no gradient for the points
    empty = hash_encode_warp(torch.zeros(0, 3), table, SMALL.resolutions())
    assert empty.shape == (0, SMALL.out_dim)


def test_torch_reference_gradcheck_float64():
    # 2 (dense: 27 <= 32 rows) and 5 (hashed: 216 > 32 rows)
    table = torch.randn(2, 32, 2, dtype=torch.float64, requires_grad=True)
    x = torch.rand(6, 3, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: hash_encode_torch(x, t, [2, 5]), (table,))


@pytest.mark.parametrize("backend", ["torch", "warp"])
def test_trilinear_interpolation_reproduces_a_linear_function(backend):
    """A dense level holding g(v) = A v / N + b at vertex v interpolates to exactly A x + b."""
    resolution, table_size = 9, 1024  # 10^3 = 1000 <= 1024: one-to-one
    a = torch.tensor([[0.3, -1.2, 2.0], [1.5, 0.25, -0.7]])
    b = torch.tensor([0.1, -0.4])
    table = torch.zeros(1, table_size, 2)
    for vx in range(resolution + 1):
        for vy in range(resolution + 1):
            for vz in range(resolution + 1):
                v = torch.tensor([vx, vy, vz], dtype=torch.float32) / resolution
                table[0, py_row((vx, vy, vz), resolution, table_size)] = a @ v + b
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(1))
    x[0] = torch.tensor([1.0, 0.0, 1.0])
    encode = hash_encode_torch if backend == "torch" else hash_encode_warp
    out = encode(x, table, [resolution])
    torch.testing.assert_close(out, x @ a.T + b, rtol=0, atol=2e-6)


@pytest.mark.parametrize("backend", ["torch", "warp"])
def test_one_hot_table_addresses_the_hashed_vertex(backend):
    """At a grid vertex the feature is the vertex's table row alone, addressed by the plain-Python hash."""
    resolution, table_size = 64, 1024
    encode = hash_encode_torch if backend == "torch" else hash_encode_warp
    for vertex in [(0, 0, 0), (3, 17, 40), (63, 1, 62), (12, 12, 12)]:
        table = torch.zeros(1, table_size, 2)
        table[0, py_row(vertex, resolution, table_size), 1] = 1.0
        x = torch.tensor([vertex], dtype=torch.float32) / resolution
        out = encode(x, table, [resolution])
        assert out[0, 0].item() == 0.0 and out[0, 1].item() == pytest.approx(1.0, abs=1e-6)


def test_module_backends_agree_and_table_initialisation():
    torch.manual_seed(0)
    warp_enc = HashGridEncoding(SMALL, backend="warp")
    torch_enc = HashGridEncoding(SMALL, backend="torch")
    torch_enc.load_state_dict(warp_enc.state_dict())
    t = warp_enc.table
    assert t.shape == (6, 4096, 2) and t.dtype == torch.float32 and t.abs().max() <= 1e-4 and t.std() > 1e-5
    x = torch.rand(100, 3)
    torch.testing.assert_close(warp_enc(x), torch_enc(x))
    warp_enc(x).square().sum().backward()
    torch_enc(x).square().sum().backward()
    torch.testing.assert_close(warp_enc.table.grad, torch_enc.table.grad, rtol=1e-4, atol=1e-12)


def test_invalid_inputs_are_rejected():
    table = torch.zeros(2, 64, 2)
    with pytest.raises(ValueError, match="x: expected a \\(N, 3\\)"):
        hash_encode_torch(torch.zeros(4, 2), table, [2, 4])
    with pytest.raises(ValueError, match="resolutions"):
        hash_encode_warp(torch.zeros(4, 3), table, [2])
    with pytest.raises(ValueError, match="power of two"):
        hash_encode_torch(torch.zeros(4, 3), torch.zeros(2, 60, 2), [2, 4])
    with pytest.raises(ValueError, match="float32"):
        hash_encode_warp(torch.zeros(4, 3), table.double(), [2, 4])
    with pytest.raises(ValueError, match="backend"):
        HashGridEncoding(SMALL, backend="cuda")
    with pytest.raises(ValueError, match="max_resolution"):
        HashGridConfig(base_resolution=32, max_resolution=16)
