"""Warp kernels of the hash encoding (:mod:`neural.field.hashgrid`), forward and table backward.

Not re-exported: use :class:`neural.field.HashGridEncoding`. Tensors are shared with Warp without copies
(``wp.from_torch``); kernels run on the tensors' device (cpu or cuda, on the current torch stream).

One launch per level over the points (on the CPU this beats one 2-D launch over levels x points: plain 1-D
indexing, and one level's rows stay in cache); a kernel thread encodes one point at one level, and the
backward pass scatters ``weight * grad`` into the level's rows of the table gradient with atomic adds.
The gradient with respect to the input points is **not** computed (the field feeds ``x`` to its MLP
directly, and the paper's normals and eikonal term use finite differences): autograd receives None for ``x``.

Warp runs a CPU launch on one core. On the CPU, ``cpu_threads`` Python threads each launch a strided
subset of the levels (Warp releases the GIL during a CPU launch), so several cores work; levels write
disjoint parts of the output and of the table gradient, so the threads never race.

The CPU forward is a second kernel: a thread encodes a block of :data:`CPU_BLOCK` points at one level in a
plain C++ loop (``wp.func_native``) that clang vectorises (with AVX-512 it gathers the corners of 16 points
at once), where a Warp kernel runs one point per thread, scalar. It makes the same operations in the same
order as the per-point kernel (which CUDA runs), so the same bits (tested), in 0.72-0.84x its time on 55k
points near lego's surface (2 threads, the median of 15 interleaved pairs, three runs).
"""

# no ``from __future__ import annotations``: Warp reads the kernels' annotations, which name closure types
import functools
from collections.abc import Sequence

import torch

from ..device import initialised_warp, kept_pool
from .hashgrid import check_encode_inputs, is_dense


@functools.cache
def _kernels(n_features: int):
    """``(vecf, forward, backward, cpu_forward)``: the vector type and the kernels for ``n_features`` floats
    per level (compiled once per value); ``cpu_forward`` is :func:`_cpu_forward_kernel`'s."""
    wp = initialised_warp()

    vecf = wp.types.vector(length=n_features, dtype=wp.float32)
    prime_y = wp.constant(wp.uint32(2654435761))
    prime_z = wp.constant(wp.uint32(805459861))

    @wp.func
    def row(cx: int, cy: int, cz: int, side: int, dense: int, mask: wp.uint32) -> int:
        if dense != 0:
            return cx + side * (cy + side * cz)
        h = wp.uint32(cx) ^ (wp.uint32(cy) * prime_y) ^ (wp.uint32(cz) * prime_z)
        return int(h & mask)

    @wp.func
    def cell(x: float, res: int):
        p = wp.clamp(x, 0.0, 1.0) * float(res)
        c = wp.min(int(p), res - 1)  # int() truncates, which is floor() for p >= 0
        return c, p - float(c)

    @wp.kernel(enable_backward=False, module="unique")
    def encode_forward(
        x: wp.array(dtype=wp.vec3),
        table: wp.array(dtype=vecf),
        level: int,
        n_levels: int,
        res: int,
        dense: int,
        table_size: int,
        out: wp.array(dtype=vecf),
    ):
        i = wp.tid()
        side = res + 1
        mask = wp.uint32(table_size - 1)
        base = level * table_size
        p = x[i]
        x0, fx = cell(p[0], res)
        y0, fy = cell(p[1], res)
        z0, fz = cell(p[2], res)
        gx = 1.0 - fx
        gy = 1.0 - fy
        gz = 1.0 - fz
        acc = table[base + row(x0, y0, z0, side, dense, mask)] * (gx * gy * gz)
        acc += table[base + row(x0 + 1, y0, z0, side, dense, mask)] * (fx * gy * gz)
        acc += table[base + row(x0, y0 + 1, z0, side, dense, mask)] * (gx * fy * gz)
        acc += table[base + row(x0 + 1, y0 + 1, z0, side, dense, mask)] * (fx * fy * gz)
        acc += table[base + row(x0, y0, z0 + 1, side, dense, mask)] * (gx * gy * fz)
        acc += table[base + row(x0 + 1, y0, z0 + 1, side, dense, mask)] * (fx * gy * fz)
        acc += table[base + row(x0, y0 + 1, z0 + 1, side, dense, mask)] * (gx * fy * fz)
        acc += table[base + row(x0 + 1, y0 + 1, z0 + 1, side, dense, mask)] * (fx * fy * fz)
        out[i * n_levels + level] = acc

    @wp.kernel(enable_backward=False, module="unique")
    def encode_backward(
        x: wp.array(dtype=wp.vec3),
        grad_out: wp.array(dtype=vecf),
        level: int,
        n_levels: int,
        res: int,
        dense: int,
        table_size: int,
        grad_table: wp.array(dtype=vecf),
    ):
        i = wp.tid()
        side = res + 1
        mask = wp.uint32(table_size - 1)
        base = level * table_size
        g = grad_out[i * n_levels + level]
        p = x[i]
        x0, fx = cell(p[0], res)
        y0, fy = cell(p[1], res)
        z0, fz = cell(p[2], res)
        gx = 1.0 - fx
        gy = 1.0 - fy
        gz = 1.0 - fz
        wp.atomic_add(grad_table, base + row(x0, y0, z0, side, dense, mask), g * (gx * gy * gz))
        wp.atomic_add(grad_table, base + row(x0 + 1, y0, z0, side, dense, mask), g * (fx * gy * gz))
        wp.atomic_add(grad_table, base + row(x0, y0 + 1, z0, side, dense, mask), g * (gx * fy * gz))
        wp.atomic_add(grad_table, base + row(x0 + 1, y0 + 1, z0, side, dense, mask), g * (fx * fy * gz))
        wp.atomic_add(grad_table, base + row(x0, y0, z0 + 1, side, dense, mask), g * (gx * gy * fz))
        wp.atomic_add(grad_table, base + row(x0 + 1, y0, z0 + 1, side, dense, mask), g * (fx * gy * fz))
        wp.atomic_add(grad_table, base + row(x0, y0 + 1, z0 + 1, side, dense, mask), g * (gx * fy * fz))
        wp.atomic_add(grad_table, base + row(x0 + 1, y0 + 1, z0 + 1, side, dense, mask), g * (fx * fy * fz))

    cpu_forward = _cpu_forward_kernel(vecf, n_features)
    return vecf, encode_forward, encode_backward, cpu_forward


#: Points a thread of the CPU forward kernel encodes in one vectorised loop.
CPU_BLOCK = 256

# One level of the encoding for points [block * CPU_BLOCK, ...) in C++: the Warp kernel's operations in its
# order (clamp, cell, the 8 corners' rows, weights, the sum over corners in the same sequence), so the same
# float32 results; the clamp sends NaN to 0, as Warp's ``fmin(fmax(0, x), 1)`` does, so rows stay in range.
# ``F`` (features per level) is substituted, so the feature loop unrolls and the point loop vectorises;
# ``assume_safety``: the output never aliases the table or the points.
_CPU_FORWARD_SNIPPET = """
    const int F = {n_features};
    const float* P = (const float*)x.data;
    const float* tb = (const float*)table.data + (long long)level * table_size * F;
    float* O = (float*)out.data + F * level;
    const long long stride = (long long)F * n_levels;
    const unsigned int mask = (unsigned int)(table_size - 1);
    const float fres = (float)res;
    const int side = res + 1;
    const int n = x.shape[0];
    const int start = block * {block};
    const int stop = start + {block} < n ? start + {block} : n;
    #pragma clang loop vectorize(assume_safety)
    for (int i = start; i < stop; ++i) {{
        float px = P[3 * i], py = P[3 * i + 1], pz = P[3 * i + 2];
        float ux = (px > 0.f ? (px < 1.f ? px : 1.f) : 0.f) * fres;
        float uy = (py > 0.f ? (py < 1.f ? py : 1.f) : 0.f) * fres;
        float uz = (pz > 0.f ? (pz < 1.f ? pz : 1.f) : 0.f) * fres;
        int x0 = (int)ux; x0 = x0 < res - 1 ? x0 : res - 1;
        int y0 = (int)uy; y0 = y0 < res - 1 ? y0 : res - 1;
        int z0 = (int)uz; z0 = z0 < res - 1 ? z0 : res - 1;
        float fx = ux - (float)x0, fy = uy - (float)y0, fz = uz - (float)z0;
        float gx = 1.f - fx, gy = 1.f - fy, gz = 1.f - fz;
        int r[8];
        if (dense) {{
            int r0 = x0 + side * (y0 + side * z0);
            r[0] = r0; r[1] = r0 + 1; r[2] = r0 + side; r[3] = r0 + side + 1;
            r[4] = r0 + side * side; r[5] = r[4] + 1; r[6] = r[4] + side; r[7] = r[4] + side + 1;
        }} else {{
            unsigned int hx0 = (unsigned int)x0, hx1 = (unsigned int)(x0 + 1);
            unsigned int hy0 = (unsigned int)y0 * 2654435761u, hy1 = (unsigned int)(y0 + 1) * 2654435761u;
            unsigned int hz0 = (unsigned int)z0 * 805459861u, hz1 = (unsigned int)(z0 + 1) * 805459861u;
            r[0] = (int)((hx0 ^ hy0 ^ hz0) & mask); r[1] = (int)((hx1 ^ hy0 ^ hz0) & mask);
            r[2] = (int)((hx0 ^ hy1 ^ hz0) & mask); r[3] = (int)((hx1 ^ hy1 ^ hz0) & mask);
            r[4] = (int)((hx0 ^ hy0 ^ hz1) & mask); r[5] = (int)((hx1 ^ hy0 ^ hz1) & mask);
            r[6] = (int)((hx0 ^ hy1 ^ hz1) & mask); r[7] = (int)((hx1 ^ hy1 ^ hz1) & mask);
        }}
        float w[8] = {{gx * gy * gz, fx * gy * gz, gx * fy * gz, fx * fy * gz,
                      gx * gy * fz, fx * gy * fz, gx * fy * fz, fx * fy * fz}};
        for (int f = 0; f < F; ++f) {{
            float acc = tb[F * r[0] + f] * w[0];
            for (int c = 1; c < 8; ++c) acc += tb[F * r[c] + f] * w[c];
            O[i * stride + f] = acc;
        }}
    }}
"""


def _cpu_forward_kernel(vecf, n_features: int):
    """The CPU forward kernel for ``n_features`` floats per level (``vecf`` :func:`_kernels`'s vector type of
    them): ``encode_forward``'s arguments, one thread per block of :data:`CPU_BLOCK` points (launch
    ``ceil(N / CPU_BLOCK)`` threads)."""
    wp = initialised_warp()
    snippet = _CPU_FORWARD_SNIPPET.format(n_features=n_features, block=CPU_BLOCK)

    @wp.func_native(snippet)
    def encode_block(
        x: wp.array(dtype=wp.vec3),
        table: wp.array(dtype=vecf),
        level: int,
        n_levels: int,
        res: int,
        dense: int,
        table_size: int,
        block: int,
        out: wp.array(dtype=vecf),
    ): ...

    @wp.kernel(enable_backward=False, module="unique")
    def encode_forward_cpu(
        x: wp.array(dtype=wp.vec3),
        table: wp.array(dtype=vecf),
        level: int,
        n_levels: int,
        res: int,
        dense: int,
        table_size: int,
        out: wp.array(dtype=vecf),
    ):
        encode_block(x, table, level, n_levels, res, dense, table_size, wp.tid(), out)

    return encode_forward_cpu


def _launch(
    kernel,
    x,
    table_in,
    table_out,
    resolutions: Sequence[int],
    table_size: int,
    cpu_threads: int,
    zero_out: bool = False,
    points_per_thread: int = 1,
) -> None:
    """Launch ``kernel`` once per level over the points of ``x``, a kernel thread per ``points_per_thread``.

    x (N,) vec3 Warp array; ``table_in`` the table (forward) or the output gradient (backward), and
    ``table_out`` the output (forward) or the table gradient (backward), as flat Warp arrays of vectors.
    ``zero_out`` (CPU only) clears each level's rows of ``table_out`` (T entries) just before its launch, in
    the launching thread: the threads share the clearing (and its page faults) and find the rows in cache.
    """
    wp = initialised_warp()
    n_levels = len(resolutions)
    stream = wp.stream_from_torch(wp.device_to_torch(x.device)) if x.device.is_cuda else None

    def run(levels) -> None:
        for level in levels:
            if zero_out:
                table_out[level * table_size : (level + 1) * table_size].zero_()
            if x.shape[0] == 0:
                continue
            res = int(resolutions[level])
            dense = int(is_dense(res, table_size))
            inputs = [x, table_in, level, n_levels, res, dense, table_size, table_out]
            dim = -(-x.shape[0] // points_per_thread)
            wp.launch(kernel, dim=dim, inputs=inputs, device=x.device, stream=stream)

    if x.device.is_cuda or cpu_threads == 1 or n_levels == 1:
        run(range(n_levels))
        return
    wp.load_module(kernel.module, device=x.device)  # compile once, before the threads race to do it
    n_threads = min(cpu_threads, n_levels)
    pool = kept_pool(n_threads, "hashgrid")
    futures = [pool.submit(run, range(k, n_levels, n_threads)) for k in range(n_threads)]
    for future in futures:
        future.result()


class _HashEncode(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, table, resolutions, cpu_threads):
        wp = initialised_warp()
        n_levels, table_size, n_features = table.shape
        vecf, forward_kernel, _, cpu_forward_kernel = _kernels(n_features)
        x = x.detach().to(torch.float32).contiguous()
        out = torch.empty((x.shape[0] * n_levels, n_features), dtype=torch.float32, device=x.device)
        on_cpu = x.device.type == "cpu"
        _launch(
            cpu_forward_kernel if on_cpu else forward_kernel,
            wp.from_torch(x, dtype=wp.vec3, requires_grad=False),
            wp.from_torch(table.detach().contiguous().view(-1, n_features), dtype=vecf, requires_grad=False),
            wp.from_torch(out, dtype=vecf, requires_grad=False),
            resolutions,
            table_size,
            cpu_threads,
            points_per_thread=CPU_BLOCK if on_cpu else 1,
        )
        ctx.save_for_backward(x)
        ctx.table_shape = table.shape
        ctx.resolutions = resolutions
        ctx.cpu_threads = cpu_threads
        return out.view(x.shape[0], n_levels * n_features)

    @staticmethod
    def backward(ctx, grad_out):
        if not ctx.needs_input_grad[1]:
            return None, None, None, None
        wp = initialised_warp()
        (x,) = ctx.saved_tensors
        n_levels, table_size, n_features = ctx.table_shape
        vecf, _, backward_kernel, _ = _kernels(n_features)
        grad_out = grad_out.to(torch.float32).contiguous().view(-1, n_features)
        # CPU: the launching threads clear each level's rows (zero_out); CUDA: cleared here, on torch's stream
        on_cpu = x.device.type == "cpu"
        allocate = torch.empty if on_cpu else torch.zeros
        grad_table = allocate(ctx.table_shape, dtype=torch.float32, device=x.device)
        _launch(
            backward_kernel,
            wp.from_torch(x, dtype=wp.vec3, requires_grad=False),
            wp.from_torch(grad_out, dtype=vecf, requires_grad=False),
            wp.from_torch(grad_table.view(-1, n_features), dtype=vecf, requires_grad=False),
            ctx.resolutions,
            table_size,
            ctx.cpu_threads,
            zero_out=on_cpu,
        )
        return None, grad_table, None, None


def hash_encode_warp(
    x: torch.Tensor, table: torch.Tensor, resolutions: Sequence[int], cpu_threads: int = 2
) -> torch.Tensor:
    """Warp twin of :func:`neural.field.hashgrid.hash_encode_torch`, differentiable in ``table`` only.

    x (N, 3) points in [0, 1]^3 (clamped), table (L, T, F) float32, resolutions L ints -> (N, L*F) float32.
    ``cpu_threads`` threads share the levels of a CPU launch (ignored on CUDA).
    """
    check_encode_inputs(x, table, resolutions)
    if table.dtype != torch.float32:
        raise ValueError(f"table: the Warp backend needs float32, got {table.dtype}")
    n_levels, table_size, _ = table.shape
    if n_levels * max(table_size, x.shape[0]) >= 2**31:
        raise ValueError(
            f"table {tuple(table.shape)}, x {tuple(x.shape)}: the Warp kernels index with int32 and need "
            "L * T and L * N below 2^31"
        )
    if not isinstance(cpu_threads, int) or cpu_threads < 1:
        raise ValueError(f"cpu_threads: expected a positive int, got {cpu_threads!r}")
    return _HashEncode.apply(x, table, tuple(int(r) for r in resolutions), cpu_threads)
