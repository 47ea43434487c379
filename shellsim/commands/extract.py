"""``shellsim extract``: re-extract an asset's adaptive shells (Procedure 2) with other parameters."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "extract",
        help="re-extract the shells M+/M- of an asset with other level-set parameters",
        description="Samples the asset's SDF f and kernel size s on a grid over its unit cube, dilates and "
        "erodes the level set (paper Procedures 1-2) and replaces shell_outer.ply / shell_inner.ply. "
        "Unset options keep the values the asset was extracted with. The cage is rebuilt on next use.",
    )
    p.add_argument("--asset", required=True, help="shipped asset name or asset directory")
    p.add_argument("--resolution", type=int, help="grid samples per axis (default 256)")
    p.add_argument("--steps", type=int, help="level-set steps T (paper: 50)")
    p.add_argument("--beta-d", type=float, help="dilation speed per unit voxel opacity (Eq. 6)")
    p.add_argument("--sigma-min", type=float, help="voxel opacity below which dilation stops (Eq. 6)")
    p.add_argument("--beta-e", type=float, help="erosion speed coefficient (Eq. 7)")
    p.add_argument("--v-max", type=float, help="speed cap, voxels per unit time")
    p.add_argument(
        "--min-part-fraction",
        type=float,
        help="drop M+ parts smaller than this fraction of the largest (default 0.05; 0 keeps all)",
    )
    p.add_argument(
        "--max-peel",
        type=int,
        help="also set the depth-peeling cap dp_max of the asset's narrow-band renderer (default 16)",
    )
    p.add_argument("--device", default="auto", help="cpu, cuda or auto (default)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import dataclasses
    import logging
    import time

    from neural.asset import command_line, load_asset, load_field, refuse_shipped, replace_shells
    from neural.errors import InputError
    from neural.shell import ShellConfig
    from neural.shell.from_field import extract_field_shells
    from shellsim.commands.args import device_option
    from shellsim.outputs import check_writable_dir

    asset = load_asset(args.asset)
    refuse_shipped(asset, "extract")
    check_writable_dir(asset.root, "--asset")  # new shells and asset.json are written there
    device = device_option(args.device)
    known = {f.name for f in dataclasses.fields(ShellConfig)}
    stored = {k: v for k, v in asset.meta.get("shell", {}).items() if k in known}
    overrides = {
        name: getattr(args, name)
        for name in ("resolution", "steps", "beta_d", "sigma_min", "beta_e", "v_max", "min_part_fraction")
        if getattr(args, name) is not None
    }
    try:
        config = ShellConfig(**{**stored, **overrides})
    except (TypeError, ValueError) as err:
        raise InputError(f"shell parameters: {err}") from None
    if args.max_peel is not None:
        try:
            narrowband = dataclasses.replace(asset.narrowband_config(), max_peel=args.max_peel)
        except ValueError as err:
            raise InputError(f"--max-peel: {err}") from None
        asset.meta["narrowband"] = dataclasses.asdict(narrowband)
    field = load_field(asset, device)
    start = time.perf_counter()
    shells = extract_field_shells(field, config, device)
    shell_meta = {**dataclasses.asdict(config), **shells.stats, "command": command_line()}
    replace_shells(asset, shells.outer, shells.inner, shell_meta)
    logging.getLogger("shellsim").info(
        "%s: new shells in %.1f s: M+ %d faces, M- %d faces, mean width %.4g",
        asset.root,
        time.perf_counter() - start,
        shells.stats["outer_faces"],
        shells.stats["inner_faces"],
        shells.stats.get("width_mean", float("nan")),
    )
