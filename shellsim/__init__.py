"""shellsim: cages, elastic simulation, wind animation and deformed rendering of adaptive-shell assets.

``shellsim.physics.fem``, ``shellsim.physics.wind`` and ``shellsim.motion.format`` work on plain numpy arrays and do not need torch.
"""

import neural  # noqa: E402, F401 (before torch loads: neural.OPENMP_SPIN_COUNT)
