from typing import Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

__version__: str

class TrimError(Exception): ...
class FileFormatError(TrimError): ...
class RegistrationError(TrimError): ...
class PlanningError(TrimError): ...
class InternalError(TrimError): ...

Array = npt.NDArray[np.float64]

def estimate_normals(
    points: Array,
    *,
    k: int = 16,
    viewpoint: Optional[Sequence[float]] = None,
    reference: Optional[Sequence[float]] = None,
) -> Array: ...
def voxel_downsample(
    points: Array, *, voxel: float, normals: Optional[Array] = None
) -> Tuple[Array, Optional[Array]]: ...
