"""Neural side of shellsim: datasets, the adaptive-kernel NeuS field, rendering, shells, training, assets.

Nothing here imports :mod:`shellsim`. Importing this package does not import torch or warp; it sets how long
idle threads of torch's OpenMP pool spin (:data:`OPENMP_SPIN_COUNT`), which takes effect when it comes
before torch's first import (as in the ``shellsim`` command, the examples and the benches).
"""

import os

#: Spins (``GOMP_SPINCOUNT``) an idle thread of torch's OpenMP pool (GNU libgomp, read when torch loads it)
#: makes before it sleeps, unless the environment sets ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY``. libgomp's
#: 300,000 kept torch's threads spinning after each of its operations, taking the cores from the Warp and
#: Embree threads that run between them: on the 2-core CPU a lego stage-1 step took 148-154 ms at 10,000 and
#: 148-161 ms at 30,000 against 184-185 ms at 300,000 and 183-208 ms at PASSIVE's none (threads that sleep at
#: once are slow to wake), and orbit frames of the lego 32-33 ms at rest and 46-47 deformed against 40-42
#: and 57-63 ms.
OPENMP_SPIN_COUNT = "30000"

if "GOMP_SPINCOUNT" not in os.environ and "OMP_WAIT_POLICY" not in os.environ:
    os.environ["GOMP_SPINCOUNT"] = OPENMP_SPIN_COUNT
