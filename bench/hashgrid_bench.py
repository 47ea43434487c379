"""Time the hash encoding, forward + backward (table gradient), per backend; print ms and peak memory.

    python bench/hashgrid_bench.py                     # 65,536 points, default HashGridConfig, cpu/cuda
    python bench/hashgrid_bench.py --points 262144 --log2-table-size 22 --max-resolution 4096

Each variant runs in its own subprocess so that the peak memory (CPU: peak resident set size above the
process's size before the first call; CUDA: torch's peak allocation) belongs to it alone. Times are the best
of ``--repeats`` runs: wall clock, and on the CPU also the process's CPU time (all threads), which other
programs sharing the cores do not inflate as much. torch runs ``--torch-threads`` intra-op threads.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

from neural.device import configure_process

VARIANTS = {
    "torch": {"backend": "torch", "cpu_threads": 1},
    "warp, 1 thread": {"backend": "warp", "cpu_threads": 1},
    "warp, 2 threads": {"backend": "warp", "cpu_threads": 2},
}


def _rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def run_variant(args: argparse.Namespace, name: str) -> dict:
    """Time one variant in this process; returns ms per forward, per forward+backward, and peak MiB."""
    import torch

    from neural.device import pick_device
    from neural.field import HashGridConfig, HashGridEncoding

    device = pick_device(args.device)
    torch.set_num_threads(args.torch_threads)
    torch.manual_seed(0)
    config = HashGridConfig(log2_table_size=args.log2_table_size, max_resolution=args.max_resolution)
    encoding = HashGridEncoding(config, **VARIANTS[name]).to(device)
    x = torch.rand(args.points, 3, device=device)
    grad = torch.randn(args.points, config.out_dim, device=device)

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    def forward_backward():
        encoding.table.grad = None
        encoding(x).backward(grad)

    rss0 = _rss_mib()
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    forward_backward()  # warm-up: kernel compilation, allocator
    timings = {}
    for label, fn in (("forward", lambda: encoding(x)), ("forward+backward", forward_backward)):
        with torch.no_grad() if label == "forward" else torch.enable_grad():
            sync()
            wall, cpu = [], []
            for _ in range(args.repeats):
                start, start_cpu = time.perf_counter(), time.process_time()
                fn()
                sync()
                wall.append(time.perf_counter() - start)
                cpu.append(time.process_time() - start_cpu)
        timings[label] = 1e3 * min(wall)
        timings[label + " cpu"] = 1e3 * min(cpu)
    if device == "cuda":
        peak = torch.cuda.max_memory_allocated() / 2**20
    else:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10 - rss0
    return {"device": device, **timings, "peak_mib": peak}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=65536)
    parser.add_argument("--log2-table-size", type=int, default=19)
    parser.add_argument("--max-resolution", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=10, help="timed repetitions; the best is reported")
    parser.add_argument("--device", default="auto", help="cpu, cuda or auto")
    parser.add_argument("--torch-threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--variant", choices=sorted(VARIANTS), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.variant:
        print(json.dumps(run_variant(args, args.variant)))
        return
    print(
        f"hash encoding, {args.points} points, T=2^{args.log2_table_size}, max res {args.max_resolution}, "
        f"torch threads {args.torch_threads}: best of {args.repeats}, ms wall (ms CPU), peak MiB"
    )
    for name in VARIANTS:
        argv = [sys.executable, __file__, *sys.argv[1:], "--variant", name]
        done = subprocess.run(argv, capture_output=True, text=True, check=True)
        r = json.loads(done.stdout.strip().splitlines()[-1])
        print(
            f"  {name:<16} [{r['device']}] forward {r['forward']:8.1f} ({r['forward cpu']:7.1f})   "
            f"forward+backward {r['forward+backward']:8.1f} ({r['forward+backward cpu']:7.1f})   "
            f"peak {r['peak_mib']:7.1f}"
        )


if __name__ == "__main__":
    configure_process()
    main()
