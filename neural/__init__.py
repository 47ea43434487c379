"""Neural side of shellsim: datasets, the adaptive-kernel NeuS field, rendering, shells, training, assets.

Nothing here imports :mod:`shellsim`. Importing this package does not import torch or warp.
"""
