"""Cut the object out of a captured asset (issue 43): a new asset whose shells hold only the object (a body
that can be caged, simulated and deformed like any asset) and which keeps the capture's other shells as its
**backdrop**, the rest of the same field, drawn around it at rest in every frame.

The region is a box, a ball (``center``, ``radius``) or, when neither is given, the one
:func:`neural.shell.cutout.propose_cut` finds: the connected part of the surface the cameras look at,
above the supporting plane found in the field (a table, else the wall it hangs on). The plane is the
region's floor, and a table becomes the asset's ``up`` (so the body stands on the ground of a shot as it
stood on its table). The field's weights are copied; ``asset.json`` records the cut (``cut``: box and
plane) and the backdrop's shells (``files``).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from neural.config import ShellConfig
from neural.device import DEVICES
from shellsim.errors import SettingError
from shellsim.io.outputs import holds_outputs
from shellsim.settings import check_choice, check_required, config_bounds, device_setting, floats, option

log = logging.getLogger(__name__)

#: Files of a cut asset besides an asset's own: the shells of the backdrop.
BACKDROP_FILES = {"backdrop_outer": "backdrop_outer.ply", "backdrop_inner": "backdrop_inner.ply"}


@dataclass(frozen=True)
class CutSettings:
    """What ``shellsim cut`` takes."""

    asset: str = option(
        help="the captured asset (shipped name or directory) to cut the object out of", required=True
    )
    out: str = option(
        help="directory of the new asset: the object as a body, the rest as its backdrop", required=True
    )
    box: tuple[float, ...] | None = option(
        help="the object's box in the asset's units, X0,Y0,Z0,X1,Y1,Z1",
        parse=floats(6),
        metavar="X0,Y0,Z0,X1,Y1,Z1",
        shown_default="proposed from the field",
    )
    center: tuple[float, float, float] | None = option(
        help="centre X,Y,Z of a ball holding the object (with --radius); the object is the surface in it "
        "above the supporting plane",
        parse=floats(3),
        metavar="X,Y,Z",
        shown_default="the point the cameras look at",
    )
    radius: float | None = option(help="radius of that ball", shown_default="the asset's object ball")
    resolution: int = option(ShellConfig.resolution, help="grid samples per axis of the body's shells")
    device: str = option("auto", help="cpu, cuda or auto")

    def __post_init__(self):
        check_required(self)
        if self.box is not None and (self.center is not None or self.radius is not None):
            raise SettingError("box", "names the object alone: give it or {center} and {radius}, not both")
        if self.radius is not None and not self.radius > 0:
            raise SettingError("radius", "must be > 0", value=self.radius)
        with config_bounds(self, {(ShellConfig, "resolution"): "resolution"}):
            ShellConfig(resolution=self.resolution)
        check_choice("device", self.device, DEVICES)


@dataclass(frozen=True)
class CutResult:
    """The cut asset: ``asset`` its directory, ``cut`` the region (:class:`neural.shell.cutout.Cut`),
    ``outer_faces`` / ``inner_faces`` of the body's shells, ``seconds`` the wall time."""

    asset: Path
    cut: object
    outer_faces: int
    inner_faces: int
    seconds: float


@holds_outputs
def cut(settings: CutSettings) -> CutResult:
    """Write the cut asset of ``settings.asset`` to ``settings.out``."""
    import numpy as np

    from neural.asset import command_line, load_asset, load_field, write_meta
    from neural.errors import InputError
    from neural.files import write_atomically
    from neural.shell.cutout import Cut, cut_shells, is_table, propose_cut
    from shellsim.io.outputs import check_writable_dir, lock_output
    from shellsim.jobs.extract import asset_shell_config

    asset = load_asset(settings.asset)
    if asset.cut is not None:
        raise SettingError("asset", "is a cut already: cut the asset it was cut from", value=asset.root)
    out = Path(settings.out)
    if out.resolve() == asset.root.resolve():
        raise SettingError("out", "must differ from the asset's directory", value=out)
    if (out / "asset.json").exists():
        raise SettingError("out", "holds an asset already; choose another directory or delete it", value=out)
    lock_output(check_writable_dir(out, "out"), "out")
    given = None
    if settings.box is not None:  # an empty box is refused before any work
        given = Cut(np.array(settings.box[:3]), np.array(settings.box[3:]))
    device = device_setting(settings.device)
    start = time.perf_counter()
    field = load_field(asset, device)
    region = propose_cut(field, asset.up, settings.center, settings.radius, given, str(device))
    config = asset_shell_config(asset, {"resolution": settings.resolution})
    shells = cut_shells(field, region, config, str(device))
    if not len(shells.outer.faces):
        raise InputError(f"{asset.root}: the field holds nothing inside the cut {region.to_dict()}")
    stands = region.normal is not None and is_table(region.normal, asset.up)  # on a table, not on a wall
    out.mkdir(parents=True, exist_ok=True)
    files = {**asset.meta["files"], **BACKDROP_FILES}
    write_atomically(
        out / files["field"], lambda tmp: Path(tmp).write_bytes(asset.file("field").read_bytes())
    )
    for key, mesh in (("shell_outer", shells.outer), ("shell_inner", shells.inner)):
        write_atomically(out / files[key], lambda tmp, m=mesh: m.export(tmp, file_type="ply"))
    for key, source in (("backdrop_outer", "shell_outer"), ("backdrop_inner", "shell_inner")):
        data = asset.file(source).read_bytes()
        write_atomically(out / files[key], lambda tmp, d=data: Path(tmp).write_bytes(d))
    meta = {
        **asset.meta,
        "name": out.name,
        "files": files,
        "up": (region.normal if stands else asset.up).tolist(),
        "shell": {**dataclasses.asdict(config), **shells.stats},
        "cut": {**region.to_dict(), "from": asset.name, "command": command_line()},
    }
    write_meta(out, meta)
    result = CutResult(
        out, region, shells.stats["outer_faces"], shells.stats["inner_faces"], time.perf_counter() - start
    )
    log.info("%s: the object cut out in %.1f s: %s", out, result.seconds, region.to_dict())
    return result
