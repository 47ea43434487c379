"""shellsim: cages, elastic simulation, wind animation and deformed rendering of adaptive-shell assets.

``shellsim.fem``, ``shellsim.wind`` and ``shellsim.motion`` work on plain numpy arrays and do not need torch.
"""
