"""The paper's neural field (Sec. 4.1): hash-grid encoding, SH direction encoding, geometry + radiance MLPs.

Importing this package imports torch but not Warp; the Warp kernels compile on first use.
"""

from .hashgrid import HashGridConfig, HashGridEncoding, hash_encode_torch
from .network import FieldConfig, Geometry, ShellField
from .sh import spherical_harmonics

__all__ = [
    "FieldConfig",
    "Geometry",
    "HashGridConfig",
    "HashGridEncoding",
    "ShellField",
    "hash_encode_torch",
    "spherical_harmonics",
]
