"""The array types the floors annotate with, each defined once.

``Array`` is what a signal, a grid or a parameter vector is: float64, of any shape. numpy's
functions that may widen the type (``np.asarray(x, float)``, ``np.linspace``, arithmetic with
an unknown array) are typed by numpy's stubs as ``floating[Any]``; a function that returns such
a value as an ``Array`` converts it where it is made (``np.asarray(..., dtype=np.float64)``), so
the annotation says what the data is, not what a stub could infer.
"""

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

__all__ = ["Array", "BoolArray", "IntArray"]

#: a float64 array of any shape: a signal, a grid, a parameter vector
Array: TypeAlias = NDArray[np.float64]
#: a mask over an :data:`Array`
BoolArray: TypeAlias = NDArray[np.bool_]
#: indices into an :data:`Array`
IntArray: TypeAlias = NDArray[np.intp]
