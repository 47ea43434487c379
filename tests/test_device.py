"""neural.device.pick_device: the one device choice (torch or Warp), its errors speaking of values, and the
CLI's ``--device`` naming the option; the processor a timing is recorded with; the process-wide settings
(OpenMP spin count, denormals flushed in each torch thread, Warp quiet) made by the entry points'
neural.device.configure_process and never by importing the packages."""

from __future__ import annotations

import os
import platform
import re
import subprocess
import sys

import pytest
import torch
import warp as wp

from neural.device import OPENMP_SPIN_COUNT, cpu_description, pick_device, processor
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


def _python(code: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``code`` run in a fresh interpreter with torch's pool at 2 threads, without the spin settings of this
    test run (``env`` adds some)."""
    clean = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    return subprocess.run(
        [sys.executable, "-c", code],
        env={**clean, "OMP_NUM_THREADS": "2", **(env or {})},
        capture_output=True,
        text=True,
        check=True,
    )


#: Prints the spin count, torch's threads, how many of 4M denormal products are not flushed to zero (the
#: product runs on every thread of torch's pool) and Warp's log level.
SETTINGS = """
import os
import torch, warp
x = torch.full((1 << 22,), 1e-39)
print(os.environ.get("GOMP_SPINCOUNT"), torch.get_num_threads(), int(torch.count_nonzero(x * 1.0)),
      warp.config.log_level == warp.LOG_INFO)
"""

IMPORT_ALL = """
import importlib, pkgutil
import neural, shellsim
for package in (neural, shellsim):
    for module in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
        importlib.import_module(module.name)
"""

ENTRY_POINT = """
from neural.device import configure_process
configure_process()
"""


@pytest.mark.slow
@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="FTZ/DAZ are x86 settings")
def test_importing_the_packages_changes_nothing_process_wide():
    """Every module of neural and shellsim imported: no spin count, denormals kept on every thread, Warp's log
    level as it was; after the entry point's call (the check can fail): all set."""
    assert _python(IMPORT_ALL + SETTINGS).stdout.split() == ["None", "2", str(1 << 22), "True"]
    assert _python(ENTRY_POINT + SETTINGS).stdout.split() == ["30000", "2", "0", "False"]


@pytest.mark.parametrize(
    ("env", "expected"),
    [({}, "30000"), ({"GOMP_SPINCOUNT": "5"}, "5"), ({"OMP_WAIT_POLICY": "ACTIVE"}, "None")],
)
def test_the_entry_point_sets_openmp_spinning_unless_the_user_did(env, expected):
    """configure_process sets GOMP_SPINCOUNT (read by torch's libgomp when torch loads) to
    neural.device.OPENMP_SPIN_COUNT, but leaves a user's GOMP_SPINCOUNT or OMP_WAIT_POLICY alone."""
    done = _python(ENTRY_POINT + "import os; print(os.environ.get('GOMP_SPINCOUNT'))", env)
    assert done.stdout.split() == [expected] and OPENMP_SPIN_COUNT == "30000"


@pytest.mark.slow
def test_torch_loaded_first_is_a_warning():
    """The spin count cannot reach a torch that is already loaded: configure_process says so."""
    assert "GOMP_SPINCOUNT does not apply" not in _python(ENTRY_POINT + "import torch").stderr
    assert "GOMP_SPINCOUNT does not apply" in _python("import torch\n" + ENTRY_POINT).stderr


def test_the_command_makes_the_settings_first(monkeypatch, tmp_path, capsys):
    """``shellsim`` calls configure_process once per run, verbose as asked."""
    calls = []
    monkeypatch.setattr("shellsim.cli.main.configure_process", lambda verbose: calls.append(verbose))
    for argv, verbose in ((["simulate"], False), (["-v", "simulate"], True)):
        assert main([*argv, "--mesh", str(tmp_path / "none.ply")]) == 2
        assert calls[-1] is verbose and len(calls) == 1 + verbose


WARP_KERNEL = """
import sys
import warp as wp
if sys.argv[1] == "configured":
    from neural.device import configure_process
    configure_process()

@wp.kernel
def double(x: wp.array(dtype=float)):
    x[wp.tid()] = 2.0 * x[wp.tid()]

wp.launch(double, 4, inputs=[wp.zeros(4, dtype=float, device="cpu")], device="cpu")
wp.synchronize()
"""

#: What Warp prints unless told not to: its banner, its CUDA probe (on machines without a GPU) and a line per
#: module loaded.
WARP_NOISE = re.compile(
    r"^Warp \d|Could not find or load the NVIDIA CUDA driver|^Module .* load on device", re.M
)


@pytest.mark.slow
def test_the_entry_point_keeps_warp_quiet(tmp_path):
    """A kernel built and run after configure_process prints nothing; without it Warp's lines appear (the
    check can fail). The kernel cache is fresh, so the module is built, not only loaded."""
    script = tmp_path / "kernel.py"
    script.write_text(WARP_KERNEL)

    def printed(mode: str) -> str:
        env = {**os.environ, "WARP_CACHE_PATH": str(tmp_path / f"cache-{mode}")}
        done = subprocess.run(
            [sys.executable, str(script), mode], env=env, capture_output=True, text=True, check=True
        )
        return done.stdout + done.stderr

    assert WARP_NOISE.search(printed("plain"))
    assert not WARP_NOISE.search(printed("configured")), printed("configured")
