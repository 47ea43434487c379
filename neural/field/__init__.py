"""The paper's neural field (Sec. 4.1): hash-grid encoding, SH direction encoding, geometry + radiance MLPs.

Importing this package imports torch but not Warp; the Warp kernels compile on first use. It also flushes
float denormals to zero on the CPU (:func:`neural.device.flush_denormals`), before torch starts the threads
that inherit the setting.
"""

from ..device import flush_denormals
from .hashgrid import HashGridConfig, HashGridEncoding, hash_encode_torch
from .network import FieldConfig, Geometry, ShellField
from .sh import spherical_harmonics

flush_denormals()

__all__ = [
    "FieldConfig",
    "Geometry",
    "HashGridConfig",
    "HashGridEncoding",
    "ShellField",
    "hash_encode_torch",
    "spherical_harmonics",
]
