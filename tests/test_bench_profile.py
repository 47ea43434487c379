"""bench/profile_bench.py's part timers: which label a call lands under (nested calls under the outermost
part running), that a timed part holds the time of the parts inside it, that patching a staticmethod and a
torch.autograd.Function's backward keeps them working and timed, and that restoring puts back the very
objects patched."""

import sys
import types
from pathlib import Path

import torch

from neural.field import hashgrid_warp
from neural.field.hashgrid import HashGridEncoding

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from profile_bench import PartTimers, patch_encoding, patched  # noqa: E402


class Tool:
    @staticmethod
    def scale(x, k=2):
        return x * k


def test_nested_calls_land_under_the_outer_part_and_are_restored():
    module = types.SimpleNamespace()
    module.inner = lambda x: Tool.scale(x, k=3)
    module.outer = lambda x: module.inner(x) + 1
    originals = (module.inner, module.outer, Tool.__dict__["scale"])
    timers = PartTimers("cpu")
    with patched(timers):
        timers.patch(module, "outer", "outer")
        timers.patch(module, "inner", "inner")
        timers.patch(Tool, "scale", "scale")
        assert module.outer(2) == 7  # the patched functions still compute what they did
        assert Tool().scale(5) == 10 and Tool.scale(5, k=1) == 5
        assert module.inner(1) == 3
    seconds = timers.snapshot()
    assert set(seconds) == {"outer", "outer / inner", "outer / scale", "scale", "inner", "inner / scale"}
    assert seconds["outer"] >= seconds["outer / inner"] >= seconds["outer / scale"] >= 0.0
    assert (module.inner, module.outer, Tool.__dict__["scale"]) == originals
    assert isinstance(Tool.__dict__["scale"], staticmethod)


def test_the_warp_encodings_backward_is_timed_inside_backward():
    encoding = HashGridEncoding(backend="warp")
    forward, backward = HashGridEncoding.__dict__["forward"], hashgrid_warp._HashEncode.__dict__["backward"]
    x = torch.rand(64, 3, generator=torch.Generator().manual_seed(0))
    reference = torch.autograd.grad(encoding(x).square().sum(), encoding.parameters())
    timers = PartTimers("cpu")
    with patched(timers):
        timers.patch(torch.Tensor, "backward", "backward")
        patch_encoding(timers)
        encoding.zero_grad()
        encoding(x).square().sum().backward()
    assert set(timers.snapshot()) == {
        "hash encoding forward",
        "backward",
        "backward / hash encoding backward",
    }
    gradients = [p.grad for p in encoding.parameters()]
    assert all(torch.equal(g, r) for g, r in zip(gradients, reference, strict=True))
    assert HashGridEncoding.__dict__["forward"] is forward
    assert hashgrid_warp._HashEncode.__dict__["backward"] is backward
