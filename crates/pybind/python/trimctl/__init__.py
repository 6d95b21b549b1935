"""trimctl: zone-layered ultrafast-laser trimming of deformed freeform parts.

Registration and planning for scripting. All lengths are millimetres, angles degrees at this
interface. Arrays are numpy float64: points and vectors as (N, 3), galvo points as (N, 2).
Options are keyword-only. Errors from the library derive from :class:`TrimError`; a wrong
argument shape, dtype or a non-finite value raises :class:`ValueError` naming the argument.
What the library warns of (a text file whose last line has no line end) is a
:class:`TrimWarning`, a :class:`UserWarning`.
"""

from ._native import (
    ContourInspection,
    FileFormatError,
    IcpResult,
    Inspection,
    UmeyamaResult,
    InternalError,
    Path,
    PlanningError,
    RegistrationError,
    TrimError,
    TrimWarning,
    __version__,
    estimate_normals,
    icp,
    inspect,
    read_path,
    read_points,
    umeyama,
    voxel_downsample,
    write_path,
    write_points,
)

from ._workflow import (
    Beam,
    ContourQuality,
    DemoCase,
    Layer,
    Plan,
    Registration,
    ScanPoses,
    Zone,
    hatch,
    merge_scan_files,
    merge_scans,
    plan,
    read_poses,
    register_path,
    synth,
)

__all__ = [
    "Beam",
    "ContourInspection",
    "ContourQuality",
    "DemoCase",
    "Inspection",
    "Layer",
    "Plan",
    "Registration",
    "ScanPoses",
    "Zone",
    "hatch",
    "merge_scan_files",
    "merge_scans",
    "plan",
    "read_poses",
    "register_path",
    "synth",
    "FileFormatError",
    "IcpResult",
    "UmeyamaResult",
    "InternalError",
    "Path",
    "PlanningError",
    "RegistrationError",
    "TrimError",
    "TrimWarning",
    "__version__",
    "estimate_normals",
    "icp",
    "inspect",
    "read_path",
    "read_points",
    "umeyama",
    "voxel_downsample",
    "write_path",
    "write_points",
]
