"""Array aliases shared by every part: one definition, imported everywhere.

Shapes are stated where the arrays are used; these names only fix the dtype.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

Array: TypeAlias = NDArray[np.float64]
"""Float64 array: positions, velocities, distances (metres, m/s)."""
F32Array: TypeAlias = NDArray[np.float32]
"""Float32 array: observations and actions as the brains take and give them."""
IntArray: TypeAlias = NDArray[np.int64]
"""Int64 array: robot ids, slot indices, counts."""
BoolArray: TypeAlias = NDArray[np.bool_]
"""Boolean array: masks."""
