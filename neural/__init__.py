"""Neural side of shellsim: datasets, the adaptive-kernel NeuS field, rendering, shells, training, assets.

Nothing here imports :mod:`shellsim`. Importing this package imports neither torch nor Warp and changes
nothing process-wide: a program's entry point does that (:func:`neural.device.configure_process`).
"""
