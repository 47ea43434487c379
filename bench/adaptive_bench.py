"""The paper's point on the furry bunny: the shell is thin on the bare ceramic skin and wide in the fur.

    python bench/adaptive_bench.py --asset furry_bunny --data ../shared/data/furry_bunny
    python bench/adaptive_bench.py --asset /tmp/probe --data ../shared/data/furry_bunny --views 3 \
        --no-full-ray
    python bench/adaptive_bench.py --asset furry_bunny --data ../shared/data/furry_bunny --no-full-ray \
        --kernel-scan 0.5 0.7 1.4 2

Prints, for surface points of the bunny labelled fur or skin by their place on the body (not by anything the
field learned): the band width there (distance to M+ plus distance to M-, world units), the kernel size s
and |grad f|; then held-out PSNR (every 8th view, narrow band and full ray of the same field) and the
narrow band's samples per pixel over fur pixels and over skin pixels.

Labelling (scene facts of ``furry_bunny``, z up, read off its training images and the surface points of a
trained field): the pedestal's flat top is at ``z = PEDESTAL_TOP``; the bunny stands on it, the red cube on
its rim reaches ``CONTACT`` above it, as do the bunny's feet where they join the pedestal; neither is
labelled. With the bunny's top ``z1`` (its highest surface points) and its height ``z1 - PEDESTAL_TOP``:
*fur* is the upward-facing part (normal z > 0.3) of the upper 45 % (the back and the ears), *skin* the lower
33 % (belly, lower flanks, chest; the face at mid height is left out with the band between). Overlaid on
training views r_0, r_3, r_8 and r_50 the fur points fall on the brown fur and the skin points on white.

``--kernel-scan K ...`` asks whether the photos favour other kernels than the learned ones: with s multiplied
by each K in the fur's part of the volume (above the fur's height), then in the skin's (below the skin's), it
prints the PSNR over fur pixels and over skin pixels (the occupancy-grid renderer, fitted to each changed
field, since the shells were cut for the learned s). The networks were trained with the learned s, so this
measures whether s sits at an optimum of the trained field, not what a field trained otherwise would reach.

The shells were extracted from the stage-1 field; ``s`` and ``|grad f|`` are the asset's (after stage 2,
which has no eikonal term: expect ``|grad f|`` above 1 there).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from neural.device import configure_process

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

PEDESTAL_TOP = -0.57  # world z of the pedestal's top face (see the module docstring)
CONTACT = 0.15  # height above the pedestal of the cube's top and of the bunny's feet: not labelled
FUR_FROM, SKIN_BELOW, FUR_NORMAL_Z = 0.55, 0.33, 0.3


def height_parts(z, z_range: tuple[float, float]):
    """(fur's, skin's) boolean masks (N,) of world heights z (N,) (numpy or torch): clear of the pedestal's
    contacts, above ``FUR_FROM`` of the bunny's height extent ``z_range`` (z0, z1) from :func:`bunny_height`,
    or below ``SKIN_BELOW`` of it."""
    z0, z1 = z_range
    rel = (z - z0) / (z1 - z0)
    bunny = z > PEDESTAL_TOP + CONTACT
    return bunny & (rel > FUR_FROM), bunny & (rel < SKIN_BELOW)


def label_points(points: np.ndarray, normals: np.ndarray, z_range: tuple[float, float]) -> np.ndarray:
    """Labels (N,) int8 of world points (N, 3) with outward unit normals (N, 3): 1 fur (the upward-facing
    points of the fur's height), 0 skin, -1 neither (:func:`height_parts`)."""
    fur_height, skin_height = height_parts(points[:, 2], z_range)
    labels = np.full(len(points), -1, dtype=np.int8)
    labels[fur_height & (normals[:, 2] > FUR_NORMAL_Z)] = 1
    labels[skin_height] = 0
    return labels


def bunny_height(points: np.ndarray) -> tuple[float, float]:
    """(z0, z1): the pedestal's top and the bunny's top (99.9th percentile of the surface points' z)."""
    return PEDESTAL_TOP, float(np.percentile(points[:, 2], 99.9))


def surface_points(field, outer, n: int, seed: int = 0):
    """Points of the field's ``f = 0`` set: area samples of M+ moved to f = 0 by Newton steps along grad f.

    Returns points (M, 3), unit normals grad f / |grad f| (M, 3), |grad f| (M,), s (M,) (float64 numpy);
    points that do not converge (|f| > 1e-3 after 8 steps) are dropped."""
    import torch
    import trimesh

    from neural.losses import finite_difference_gradient

    x = torch.as_tensor(trimesh.sample.sample_surface(outer, n, seed=seed)[0], dtype=torch.float32)
    eps = 1e-3 / float(field.scale)
    with torch.no_grad():
        for _ in range(8):
            f = field.sdf(x)
            g = finite_difference_gradient(field.sdf, x, eps)
            x = x - (f / (g * g).sum(1).clamp_min(1e-12))[:, None] * g
        f, s = field.sdf_and_kernel(x)
        g = finite_difference_gradient(field.sdf, x, eps)
    ok = (f.abs() < 1e-3).numpy()
    gn = g.norm(dim=1)
    normals = (g / gn.clamp_min(1e-12)[:, None]).numpy()
    return x.numpy()[ok].astype(np.float64), normals[ok], gn.numpy()[ok], s.numpy()[ok]


def band_width(points: np.ndarray, outer, inner) -> np.ndarray:
    """(N,) distance from each point to M+ plus distance to M- (libigl, unsigned)."""
    import igl

    def dist(mesh):
        d2, _, _ = igl.point_mesh_squared_distance(
            points, np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
        )
        return np.sqrt(d2)

    return dist(outer) + dist(inner)


def pixel_labels(intersector, outer, cameras, index: int, z_range) -> np.ndarray:
    """(H, W) labels of camera ``index``'s pixels: that of the point where the pixel's ray first enters M+."""
    from neural.data import camera_rays

    origins, dirs = camera_rays(cameras, index)
    o, d = origins.numpy().astype(np.float64), dirs.numpy().astype(np.float64)
    t, face = intersector.first_hit("outer", o, d)
    hit = np.isfinite(t)
    labels = np.full(len(o), -1, dtype=np.int8)
    pts = o[hit] + t[hit, None] * d[hit]
    normals = np.asarray(outer.face_normals)[face[hit]]
    labels[hit] = label_points(pts, normals, z_range)
    return labels.reshape(int(cameras.height[index]), int(cameras.width[index]))


def kernel_scan(field, data, views, background, z_range, pixel_labels_of, factors) -> dict:
    """``{"fur": [...], "skin": [...]}``: per factor K (``factors``), the PSNR over fur pixels and over skin
    pixels of ``views`` with the kernel size s multiplied by K in that part of the volume (its height band,
    :func:`height_parts`); ``pixel_labels_of[v]`` (H, W) labels each view's pixels."""
    import torch

    from neural.render.view import fitted_occupancy_grid, occupancy_sampler, render_camera

    learned = field.geometry

    def part(x, name):
        fur_height, skin_height = height_parts(x[:, 2], z_range)
        return fur_height if name == "fur" else skin_height

    scan = {}
    try:
        for name in ("fur", "skin"):
            scan[name] = []
            for k in factors:

                def geometry(x, name=name, k=k):
                    geo = learned(x)
                    return geo._replace(inv_s=torch.where(part(x, name), geo.inv_s / k, geo.inv_s))

                field.geometry = geometry
                sampler = occupancy_sampler(fitted_occupancy_grid(field), field)
                errors = {1: [], 0: []}
                for v in views:
                    image, _ = render_camera(field, data.cameras, int(v), sampler, background)
                    error = ((image - data.images[v]) ** 2).mean(-1)
                    for label in errors:
                        errors[label].append(error[pixel_labels_of[int(v)] == label])
                psnr_of = {lab: float(-10 * np.log10(np.concatenate(e).mean())) for lab, e in errors.items()}
                row = {"factor": k, "psnr_fur_pixels": psnr_of[1], "psnr_skin_pixels": psnr_of[0]}
                scan[name].append(row)
    finally:
        field.geometry = learned
    return scan


def run(args) -> dict:
    import torch

    from neural.asset import load_asset, load_field
    from neural.data import load_dataset
    from neural.metrics import psnr
    from neural.render.raycast import EmbreeCaster
    from neural.render.view import full_ray_sampler, narrow_band_sampler, render_camera

    torch.set_num_threads(args.threads)
    asset = load_asset(args.asset)
    field = load_field(asset, "cpu")
    outer, inner = asset.outer_mesh(), asset.inner_mesh()
    pts, normals, grad_norm, s = surface_points(field, outer, args.points)
    z_range = bunny_height(pts)
    labels = label_points(pts, normals, z_range)
    width = band_width(pts, outer, inner)
    report = {"asset": str(asset.root), "bunny_z": z_range, "points": {}}
    for name, k in (("fur", 1), ("skin", 0)):
        sel = labels == k
        report["points"][name] = {
            "count": int(sel.sum()),
            "band_median": float(np.median(width[sel])),
            "band_p90": float(np.percentile(width[sel], 90)),
            "s_median": float(np.median(s[sel])),
            "grad_norm_median": float(np.median(grad_norm[sel])),
        }
    fur, skin = report["points"]["fur"], report["points"]["skin"]
    report["band_ratio"] = fur["band_median"] / skin["band_median"]

    data = load_dataset(
        args.data, downscale=args.downscale or asset.training_downscale, background=asset.background
    )
    views = np.asarray(data.test_idx)[: args.views]
    bg = torch.as_tensor(asset.background, dtype=torch.float32)
    intersector = EmbreeCaster(outer, inner)
    samplers = {"narrow_band": narrow_band_sampler(intersector, asset.narrowband_config())}
    if not args.no_full_ray:
        samplers["full_ray"] = full_ray_sampler(field)
    labels_of = {int(v): pixel_labels(intersector, outer, data.cameras, int(v), z_range) for v in views}
    spp = {"fur": [], "skin": []}
    for name, sampler in samplers.items():
        psnrs, all_spp = [], []
        for v in views:
            image, stats = render_camera(field, data.cameras, int(v), sampler, bg)
            psnrs.append(psnr(image, data.images[v]))
            all_spp.append(stats["samples_per_pixel"])
            if name == "narrow_band":
                lab = labels_of[int(v)]
                spp["fur"].append(stats["counts"][lab == 1])
                spp["skin"].append(stats["counts"][lab == 0])
        report[name] = {"psnr": float(np.mean(psnrs)), "samples_per_pixel": float(np.mean(all_spp))}
    report["narrow_band"]["spp_fur"] = float(np.concatenate(spp["fur"]).mean())
    report["narrow_band"]["spp_skin"] = float(np.concatenate(spp["skin"]).mean())
    report["views"] = [int(v) for v in views]
    if args.kernel_scan:
        report["kernel_scan"] = kernel_scan(field, data, views, bg, z_range, labels_of, args.kernel_scan)
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--asset", required=True, help="asset name or directory")
    parser.add_argument("--data", required=True, help="the furry_bunny dataset")
    parser.add_argument("--downscale", type=int, default=None, help="default: the asset's training downscale")
    parser.add_argument("--views", type=int, default=None, help="only the first N held-out views")
    parser.add_argument("--no-full-ray", action="store_true", help="skip the (slow) full-ray reference")
    parser.add_argument("--points", type=int, default=40000, help="surface samples for the band widths")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", default=None, help="also write the figures to this JSON file")
    parser.add_argument(
        "--kernel-scan",
        type=float,
        nargs="+",
        default=None,
        metavar="K",
        help="also print fur and skin pixels' PSNR with s times K in the fur's, then skin's part (1 added)",
    )
    args = parser.parse_args()
    if args.kernel_scan:
        args.kernel_scan = sorted({1.0, *args.kernel_scan})
    r = run(args)
    z0, z1 = r["bunny_z"]
    print(f"{r['asset']}: bunny surface z {z0:.3f} .. {z1:.3f} (world units)")
    for name in ("fur", "skin"):
        p = r["points"][name]
        print(
            f"  {name:4s} ({p['count']:5d} points): band median {p['band_median']:.4f} "
            f"(p90 {p['band_p90']:.4f}), s median {p['s_median']:.5f}, "
            f"|grad f| median {p['grad_norm_median']:.3f}"
        )
    print(f"  band fur / skin: {r['band_ratio']:.2f}")
    nb = r["narrow_band"]
    print(
        f"  narrow band PSNR {nb['psnr']:.2f} dB, {nb['samples_per_pixel']:.2f} samples/pixel "
        f"(fur pixels {nb['spp_fur']:.2f}, skin pixels {nb['spp_skin']:.2f}); views {r['views']}"
    )
    if "full_ray" in r:
        fr = r["full_ray"]
        print(
            f"  full ray    PSNR {fr['psnr']:.2f} dB ({nb['psnr'] - fr['psnr']:+.2f} dB narrow band), "
            f"{fr['samples_per_pixel']:.1f} samples/pixel"
        )
    for part, rows in r.get("kernel_scan", {}).items():
        print(f"  s times K in the {part}'s part of the volume: PSNR over fur pixels / over skin pixels (dB)")
        for row in rows:
            fur, skin = row["psnr_fur_pixels"], row["psnr_skin_pixels"]
            print(f"    K {row['factor']:4.2f}: {fur:6.2f} / {skin:6.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    configure_process()
    main()
