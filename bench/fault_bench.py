"""The fault-injection matrix (issue 44): every writer x {I/O error, disk full, kill} at every call index
up to ``--bound``; prints the cases run and the cases left inconsistent of each (see ``tests/faults.py`` and
``tests/fault_writers.py``). Exits 1 if any case is inconsistent.

    python bench/fault_bench.py [--bound 400]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fault_writers import writers  # noqa: E402
from faults import FAULTS, sweep  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bound", type=int, default=400, help="largest call index to fail")
    args = parser.parse_args()
    header = f"{'writer':34}" + "".join(f"{fault:>20}" for fault in FAULTS) + f"{'seconds':>9}"
    print(header)
    print("-" * len(header))
    total = bad = 0
    with tempfile.TemporaryDirectory(prefix="shellsim-faults-") as tmp:
        for name, scenario in writers().items():
            start, row = time.perf_counter(), f"{name:34}"
            for fault in FAULTS:
                tally = sweep(lambda f, k, s=scenario, d=Path(tmp) / name: s(d, f, k), fault, args.bound)
                total, bad = total + tally.runs, bad + len(tally.inconsistent)
                row += f"{f'{tally.runs} run, {len(tally.inconsistent)} bad':>20}"
                for problem in tally.inconsistent[:3]:
                    print(f"  {name} / {fault}: {problem}", file=sys.stderr)
            print(f"{row}{time.perf_counter() - start:9.1f}", flush=True)
    print(f"{total} cases, {bad} inconsistent")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
