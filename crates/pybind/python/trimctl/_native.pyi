import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

class TrimError(Exception): ...
class FileFormatError(TrimError): ...
class RegistrationError(TrimError): ...
class PlanningError(TrimError): ...
class InternalError(TrimError): ...
class TrimWarning(UserWarning): ...

Array = npt.NDArray[np.float64]

def estimate_normals(
    points: Array,
    *,
    k: int = 16,
    viewpoint: Optional[Sequence[float]] = None,
    reference: Optional[Sequence[float]] = None,
) -> Array: ...
def voxel_downsample(
    points: Array, *, voxel_mm: float, normals: Optional[Array] = None
) -> Tuple[Array, Optional[Array]]: ...

class IcpResult:
    target_from_source: Array
    scale: float
    rmse_mm: float
    fitness: float
    correspondences: int
    iterations: int
    converged: bool
    eigenvalues: npt.NDArray[np.float64]

def icp(
    source: Array,
    target: Array,
    *,
    method: str = "point_to_plane",
    scale: bool = False,
    max_distance_mm: float = 1.0,
    max_iterations: int = 50,
    init: Optional[Array] = None,
    target_normals: Optional[Array] = None,
    kernel: Optional[Tuple[str, float]] = None,
    trim: float = 0.0,
) -> IcpResult: ...
class UmeyamaResult:
    b_from_a: Array
    scale: float
    rmse_mm: float

def umeyama(a: Array, b: Array, *, scale: bool = True) -> UmeyamaResult: ...

class ContourInspection:
    id: int
    verdict: str
    excess_height_um: float
    excess_length_mm: float
    gouge_depth_um: float
    blocked_fraction: Optional[float]
    uncertainty_um: float
    coverage: float
    reason: str
    bound_um: float
    film_thickness_um: Optional[float]
    """Thickness of the film over the opening this contour rims, µm, where the scan sees it
    from both sides (its upper side's median reading less its underside's); else ``None``."""
    film_uncertainty_um: Optional[float]
    """Standard uncertainty (k = 1) of ``film_thickness_um``, µm; ``None`` with it."""

class Inspection:
    tolerance_um: float
    noise_um: float
    contours: List[ContourInspection]
    points_measured: int
    def ids(self, verdict: str) -> List[int]: ...

def inspect(
    cad_vertices: Array,
    cad_triangles: Array,
    cad_points: Array,
    cad_normals: Array,
    path: "Path",
    scan: Array,
    *,
    init: Optional[Array] = None,
    viewpoint_mm: Optional[Tuple[float, float, float]] = None,
    tolerance_um: float = 30.0,
    band_mm: float = 0.5,
    noise_um: Optional[float] = None,
) -> Inspection: ...

PathLike = Union[str, os.PathLike]

class Path:
    def __init__(self, ids: npt.ArrayLike, points: Array, features: Array) -> None: ...
    @property
    def ids(self) -> npt.NDArray[np.int64]: ...
    @property
    def points(self) -> Array: ...
    @property
    def features(self) -> Array: ...
    @property
    def contour_ids(self) -> List[int]: ...
    @property
    def num_points(self) -> int: ...
    def contour(self, id: int) -> Tuple[Array, Array]: ...
    def __len__(self) -> int: ...

def read_points(path: PathLike) -> Tuple[Array, Optional[Array]]: ...
def write_points(path: PathLike, points: Array, *, normals: Optional[Array] = None) -> None:
    """Writes the format the extension names (.ply, .pcd, .xyz or .txt), double precision;
    refuses .stl, .csv, unknown extensions and an empty cloud, writing nothing."""
    ...
def read_path(path: PathLike) -> Path: ...
def write_path(path: PathLike, trim_path: Path) -> None: ...

class ContourQuality:
    id: int
    points: int
    scan_points: int
    coverage: float
    residual_rms_mm: Optional[float]
    degeneracy_ratio: float
    weakest_direction: Array
    support_ratio: float
    max_field_displacement_mm: float
    field_sigma_mm: float
    field_weak_direction: Array
    support_distance_mm: float
    end_support_mm: float
    model_disagreement_mm: float
    model_disagreement_faces_mm: float
    cross_sigma_mm: float
    end_sigma_mm: float
    p95_risk: Optional[float]
    opening_slide_mm: Optional[float]
    opening_gain: Optional[float]
    opening_cover_gain: Optional[float]
    scan_edge_gap_um: Optional[float]
    scan_slide_gap_um: Optional[float]
    scan_edges: Tuple[Dict[str, Any], ...]
    predicted_max_error_um: float
    part_bound_um: float
    doubt_bound_um: float
    flags: Tuple[str, ...]
    trustworthy: bool

def synth_case(params_json: str) -> dict: ...
def register_path(
    cad: Array,
    cad_normals: Array,
    scan: Array,
    path: Path,
    init: Optional[Array],
    settings_json: str,
    scan_normals: Optional[Array] = None,
) -> Tuple[Path, Dict[str, Any], Array, List[ContourQuality]]: ...
def beam_report(beam_json: str, limits_json: Optional[str] = None) -> Dict[str, float]: ...
def plan_path(
    path: Path, settings_json: str, limits_json: Optional[str] = None
) -> Tuple[Dict[str, Any], List[Dict[str, Any]], Dict[str, Any]]: ...
def merge_scans(
    scans: List[Array], poses_json: List[str], settings_json: str
) -> Array: ...
def merge_scan_files(files: List[str], poses: str, settings_json: str) -> Array: ...
def read_poses(
    path: str,
) -> Tuple[str, List[Tuple[str, Tuple[float, float, float], float, float]]]: ...
def hatch_surface(
    points: Array,
    boundary: Array,
    settings_json: str,
    normals: Optional[Array] = None,
    spot: Optional[Tuple[float, float]] = None,
) -> Path: ...
