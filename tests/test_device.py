"""neural.device.pick_device: the one device choice (torch or Warp), its errors speaking of values, and the
CLI's ``--device`` naming the option; denormals flushed in each torch thread once neural.field is imported;
the processor a timing is recorded with; the OpenMP spin count set before torch loads."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest
import torch
import warp as wp

from neural.device import cpu_description, pick_device, processor
from neural.errors import InputError
from shellsim.cli.main import main


@pytest.mark.parametrize("cuda", [False, True])
@pytest.mark.parametrize("warp", [False, True])
def test_auto_follows_the_library_that_will_run(monkeypatch, cuda, warp):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: cuda and not warp)
    monkeypatch.setattr(wp, "get_cuda_device_count", lambda: int(cuda and warp))
    gpu = "cuda:0" if warp else "cuda"
    assert pick_device("auto", warp) == pick_device(None, warp) == (gpu if cuda else "cpu")
    assert pick_device("cpu", warp) == "cpu"
    if cuda:
        assert pick_device("cuda", warp) == gpu
    else:
        with pytest.raises(InputError) as err:
            pick_device("cuda", warp)
        assert str(err.value) == "device 'cuda' requested but no CUDA device is available"


@pytest.mark.parametrize("name", ["gpu", "CUDA", "cuda:1", ""])
def test_unknown_names_are_refused_by_value(name):
    with pytest.raises(InputError) as err:
        pick_device(name)
    assert str(err.value) == f"device {name!r}: expected one of 'auto', 'cpu', 'cuda'"


@pytest.mark.parametrize("name", ["gpu", "cuda"])
def test_the_cli_names_the_option(tmp_path, capsys, monkeypatch, name):
    monkeypatch.setattr(wp, "get_cuda_device_count", lambda: 0)
    assert main(["simulate", "--mesh", str(tmp_path / "none.ply"), "--device", name]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("shellsim: error: --device: device ")
    assert repr(name) in err[0]


def test_parallel_work_takes_no_more_threads_than_torch_was_given(monkeypatch):
    """A Ray worker sets torch to one thread: the Warp casts, the inverse map and the hash grid follow."""
    import trimesh

    from neural.field.hashgrid import HashGridConfig, HashGridEncoding
    from neural.render.raycast import WarpCaster
    from shellsim.deform.inverse_map import InverseMap

    seen = []
    monkeypatch.setattr(
        "neural.field.hashgrid_warp.hash_encode_warp",
        lambda x, t, r, cpu_threads: seen.append(cpu_threads) or x,
    )
    sphere = trimesh.creation.icosphere(1)
    tets, verts = [[0, 1, 2, 3]], [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]
    encoding = HashGridEncoding(HashGridConfig(log2_table_size=10), cpu_threads=2)
    for threads in (2, 1):
        monkeypatch.setattr(torch, "get_num_threads", lambda n=threads: n)
        assert WarpCaster(sphere, sphere.copy(), device="cpu").cpu_threads == threads
        assert InverseMap(verts, tets, verts, device="cpu").cpu_threads == threads
        encoding(torch.zeros(4, 3))
    assert seen == [2, 1]


DENORMALS_KEPT = """
import sys, torch
if sys.argv[1] == "field":
    import neural.field
x = torch.full((1 << 22,), 1e-39)  # a denormal float32; the product runs on every thread of torch's pool
print(torch.get_num_threads(), int(torch.count_nonzero(x * 1.0)))
"""


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="FTZ/DAZ are x86 settings")
def test_importing_the_field_flushes_denormals_in_every_torch_thread():
    """After ``import neural.field`` a product of 4M denormals is all zeros (DAZ), on each of torch's threads,
    which inherit the setting as they start; without that import none is zero (the check can fail)."""
    env = {**os.environ, "OMP_NUM_THREADS": "2"}

    def nonzero(mode: str) -> tuple[int, int]:
        done = subprocess.run(
            [sys.executable, "-c", DENORMALS_KEPT, mode], env=env, capture_output=True, text=True, check=True
        )
        threads, count = map(int, done.stdout.split())
        return threads, count

    assert nonzero("plain") == (2, 1 << 22)
    assert nonzero("field") == (2, 0)


CPUINFO_VM = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 26
model\t\t: 2
model name\t: AMD EPYC
stepping\t: 1
flags\t\t: fpu sse2 avx2 avx512f avx512_bf16

processor\t: 1
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 1
model name\t: AMD EPYC 7B13
stepping\t: 0
flags\t\t: fpu sse2 avx2
"""


def test_the_cpu_is_described_by_its_first_processor_block():
    """Name, family, model and stepping of processor 0 (not 1's), AVX-512 from its flags (avx512_bf16 alone
    would not count); a block without those ids is its name alone; an empty text, nothing."""
    assert cpu_description(CPUINFO_VM) == "AMD EPYC (family 26, model 2, stepping 1; AVX-512)"
    second = CPUINFO_VM.split("\n\n")[1]
    assert cpu_description(second) == "AMD EPYC 7B13 (family 25, model 1, stepping 0)"
    assert cpu_description("processor : 0\nmodel name : Neoverse-N1\nflags : fp asimd\n") == "Neoverse-N1"
    assert cpu_description("processor : 0\nvendor_id : GenuineIntel\nflags : avx512f\n") == (
        "GenuineIntel (AVX-512)"
    )
    assert cpu_description("") == ""


def test_the_processor_names_the_cores_this_process_may_use():
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert processor("cpu").endswith(f", {cores} cores") and len(processor("cpu")) > len(f", {cores} cores")


SPIN_COUNT = """
import os, sys
import shellsim.cli.main  # as the shellsim command starts: torch is not loaded yet
import neural
assert "torch" not in sys.modules
print(os.environ.get("GOMP_SPINCOUNT"), neural.OPENMP_SPIN_COUNT)
"""


@pytest.mark.parametrize(
    ("env", "expected"),
    [({}, "30000"), ({"GOMP_SPINCOUNT": "5"}, "5"), ({"OMP_WAIT_POLICY": "ACTIVE"}, "None")],
)
def test_the_command_sets_openmp_spinning_unless_the_user_did(env, expected):
    """Importing the packages sets GOMP_SPINCOUNT (read by torch's libgomp when torch loads) to
    neural.OPENMP_SPIN_COUNT, but leaves a user's GOMP_SPINCOUNT or OMP_WAIT_POLICY alone."""
    clean = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    done = subprocess.run(
        [sys.executable, "-c", SPIN_COUNT], env={**clean, **env}, capture_output=True, text=True, check=True
    )
    assert done.stdout.split() == [expected, "30000"]
