"""What a render of PNG frames did (:class:`RenderResult`): the result of
:func:`shellsim.film.motion_frames.render_views`, :func:`shellsim.film.motion_frames.render_motion`,
:func:`shellsim.viz.surface.render_surface_motion` and the render job."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RenderResult:
    """The frames of one render and how long they took.

    out : directory of the PNG frames
    frames : (N,) paths of every frame asked for, in order, rendered now or kept from an earlier render
    rendered : frames rendered now; skipped : frames kept (already on disk, made the same way)
    replaced : frames on disk made otherwise (another motion, camera, size, asset), rendered again; counted
        in ``rendered``
    ms : mean milliseconds per rendered frame (None when none was rendered)
    samples_per_pixel : mean samples evaluated per pixel (None when none was rendered, or for a motion's own
        surface drawn with pyvista)
    stage_ms : mean milliseconds per frame of each stage (``build``, ``sample``, ``map``, ``shade``,
        ``world``, ``static``, ``shadow``: :data:`shellsim.film.renderer.STAGES`); empty when none was
        rendered or for a surface
    video : the MP4 assembled from ``frames``, None without one
    """

    out: Path
    frames: tuple[Path, ...]
    rendered: int
    skipped: int
    replaced: int
    ms: float | None
    samples_per_pixel: float | None
    stage_ms: dict[str, float]
    video: Path | None = None

    @classmethod
    def of_frames(
        cls, out: Path, frames: list[Path], skipped: int, replaced: int, stats: list[dict]
    ) -> RenderResult:
        """The result of rendering ``len(stats)`` of ``frames`` into ``out`` (the others kept): the mean of
        the frames' ``stats`` (each with ``ms``, optionally ``samples_per_pixel`` and ``<stage>_ms``)."""

        def mean(key: str) -> float | None:
            return float(np.mean([s[key] for s in stats])) if stats and key in stats[0] else None

        stages = [k[: -len("_ms")] for k in stats[0] if k.endswith("_ms")] if stats else []
        result = cls(
            out=Path(out),
            frames=tuple(Path(f) for f in frames),
            rendered=len(stats),
            skipped=skipped,
            replaced=replaced,
            ms=mean("ms"),
            samples_per_pixel=mean("samples_per_pixel"),
            stage_ms={stage: mean(f"{stage}_ms") for stage in stages},
        )
        if stats:
            log.debug(
                "%d frames rendered to %s (%d already there): %.1f ms per frame, stages %s",
                result.rendered,
                out,
                skipped,
                result.ms,
                {k: round(v, 2) for k, v in result.stage_ms.items()},
            )
        return result
