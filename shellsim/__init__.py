"""shellsim: cages, elastic simulation, wind animation and deformed rendering of adaptive-shell assets.

The public API is the job layer the command line runs (``shellsim NAME`` is ``NAME(NameSettings(...))``),
each job a frozen settings dataclass, one function and a result dataclass, plus the loaders a notebook
needs. Every name loads on first use: ``import shellsim`` imports neither torch nor Warp.

Assets, cages and motions:
    load_asset(name_or_dir) -> Asset; load_or_build_cage(asset, CageConfig | None) -> Cage;
    load_motion(path) -> Motion (positions (F, V, 3), times (F,), rest_vertices (V, 3), tets (T, 4))
Jobs (settings -> function -> result):
    TrainSettings -> train -> TrainResult            ExtractSettings -> extract -> ExtractResult
    FinetuneSettings -> finetune -> FinetuneResult
    PosesSettings -> poses -> PosesResult            CageSettings -> cage -> CageResult
    SimulateSettings -> simulate -> SimulateResult   WindSettings -> wind -> WindResult
    SceneSettings -> scene -> SceneResult
    RenderSettings -> render -> RenderResult         EvalSettings -> evaluate -> EvalResult (ViewMetrics)
    ExportSettings -> export -> ExportResult         SweepSettings -> sweep -> SweepResult
    InspectSettings -> inspect -> the screenshot's path (None after an interactive view)
Rendering without settings: render_views(asset, cameras, out, ...) and render_motion(asset, motion, out, ...)
    -> RenderResult.
Errors: ShellsimError (anything a user can act on), SettingError (a setting's value, naming the field).

Every job is the function of its command's name: no sub-package is named after a command (the cages are
``shellsim.tetcage``, the filming of motions and shots ``shellsim.film``, the shots ``shellsim.shot``).
``shellsim.physics`` (model, state, control, solver, driver, wind) and ``shellsim.motion.format`` work on
plain numpy arrays and do not need torch.
"""

import importlib

#: Public name -> (module, attribute), imported on first access (PEP 562).
_EXPORTS = {
    "load_asset": ("neural.asset", "load_asset"),
    "CageConfig": ("shellsim.tetcage.build", "CageConfig"),
    "load_or_build_cage": ("shellsim.tetcage.store", "load_or_build_cage"),
    "load_motion": ("shellsim.motion.read", "load_motion"),
    "TrainSettings": ("shellsim.jobs.train", "TrainSettings"),
    "TrainResult": ("shellsim.jobs.train", "TrainResult"),
    "train": ("shellsim.jobs.train", "train"),
    "FinetuneSettings": ("shellsim.jobs.finetune", "FinetuneSettings"),
    "FinetuneResult": ("shellsim.jobs.finetune", "FinetuneResult"),
    "finetune": ("shellsim.jobs.finetune", "finetune"),
    "ExtractSettings": ("shellsim.jobs.extract", "ExtractSettings"),
    "ExtractResult": ("shellsim.jobs.extract", "ExtractResult"),
    "extract": ("shellsim.jobs.extract", "extract"),
    "PosesSettings": ("shellsim.jobs.poses", "PosesSettings"),
    "PosesResult": ("shellsim.jobs.poses", "PosesResult"),
    "poses": ("shellsim.jobs.poses", "poses"),
    "CageSettings": ("shellsim.jobs.cage", "CageSettings"),
    "CageResult": ("shellsim.jobs.cage", "CageResult"),
    "cage": ("shellsim.jobs.cage", "cage"),
    "SimulateSettings": ("shellsim.jobs.simulate", "SimulateSettings"),
    "SimulateResult": ("shellsim.jobs.simulate", "SimulateResult"),
    "simulate": ("shellsim.jobs.simulate", "simulate"),
    "SceneSettings": ("shellsim.jobs.scene", "SceneSettings"),
    "SceneResult": ("shellsim.jobs.scene", "SceneResult"),
    "scene": ("shellsim.jobs.scene", "scene"),
    "WindSettings": ("shellsim.jobs.wind", "WindSettings"),
    "WindResult": ("shellsim.jobs.wind", "WindResult"),
    "wind": ("shellsim.jobs.wind", "wind"),
    "RenderSettings": ("shellsim.jobs.render", "RenderSettings"),
    "RenderResult": ("shellsim.film.result", "RenderResult"),
    "render": ("shellsim.jobs.render", "render"),
    "render_views": ("shellsim.film.motion_frames", "render_views"),
    "render_motion": ("shellsim.film.motion_frames", "render_motion"),
    "EvalSettings": ("shellsim.jobs.eval", "EvalSettings"),
    "EvalResult": ("shellsim.jobs.eval", "EvalResult"),
    "ViewMetrics": ("shellsim.jobs.eval", "ViewMetrics"),
    "evaluate": ("shellsim.jobs.eval", "evaluate"),
    "ExportSettings": ("shellsim.jobs.export", "ExportSettings"),
    "ExportResult": ("shellsim.jobs.export", "ExportResult"),
    "export": ("shellsim.jobs.export", "export"),
    "SweepSettings": ("shellsim.jobs.sweep", "SweepSettings"),
    "SweepResult": ("shellsim.jobs.sweep", "SweepResult"),
    "sweep": ("shellsim.jobs.sweep", "sweep"),
    "InspectSettings": ("shellsim.jobs.inspect", "InspectSettings"),
    "inspect": ("shellsim.jobs.inspect", "inspect"),
    "ShellsimError": ("neural.errors", "ShellsimError"),
    "SettingError": ("shellsim.errors", "SettingError"),
}

__all__ = list(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'shellsim' has no attribute {name!r}")
    module, attribute = _EXPORTS[name]
    value = getattr(importlib.import_module(module), attribute)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
