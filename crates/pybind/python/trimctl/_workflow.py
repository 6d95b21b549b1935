"""The scripting workflow: demo case, path registration, beam figures and planning.

Settings use the job.toml keys (``trimctl config --dump``): a dict here and a table there mean
the same thing, and an unknown or out-of-range key raises ``ValueError`` naming it.
"""

from __future__ import annotations

import copy
import json
import math
import numbers
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from . import _native
from ._native import ContourQuality, Path

__all__ = [
    "Beam",
    "DemoCase",
    "Layer",
    "Plan",
    "Registration",
    "Zone",
    "hatch",
    "merge_scan_files",
    "merge_scans",
    "plan",
    "read_poses",
    "ScanPoses",
    "register_path",
    "synth",
]


def _settings_json(what: str, settings: Any) -> str:
    """``settings`` (nested mappings and sequences) as JSON for the native side: numpy numbers
    and arrays become Python numbers and lists; a NaN or infinite number raises ``ValueError``
    naming ``what`` and its key (JSON has no such number, and the native side would only say
    "expected value at line 1 column 13"); a settings value that is not a mapping is refused by
    name too."""
    if settings is not None and not isinstance(settings, Mapping):
        raise ValueError(f"{what}: expected a mapping of settings, got a {type(settings).__name__}")

    def plain(key: str, v: Any) -> Any:
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, Mapping):
            return {str(k): plain(f"{key}.{k}" if key else str(k), x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(f"{key}[{i}]", x) for i, x in enumerate(v)]
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{what}: {key} = {v!r}: must be a finite number")
        return v

    return json.dumps(plain("", settings))


def _refuse_renamed(function: str, given: Mapping[str, Any], renamed: Mapping[str, str]) -> None:
    """Raises ``TypeError`` for a keyword ``function`` does not take, naming the new name of one
    that was renamed (options carry their unit: ``layer_step`` is now ``layer_step_mm``)."""
    for old in given:
        if old in renamed:
            raise TypeError(
                f"{function}(): {old}= was renamed {renamed[old]}= (the unit is in the name)"
            )
        raise TypeError(f"{function}() got an unexpected keyword argument {old!r}")


def _kw(settings: Optional[Mapping[str, Any]], **given: Any) -> Dict[str, Any]:
    """A deep copy of ``settings`` (the caller's dicts, nested ones included, are never changed)
    with the keyword options that were given (``None`` = not given) set over it."""
    if settings is not None and not isinstance(settings, Mapping):
        raise ValueError(
            f"settings: expected a mapping of job.toml keys, got a {type(settings).__name__}"
        )
    out: Dict[str, Any] = copy.deepcopy(dict(settings or {}))
    out.update({k: v for k, v in given.items() if v is not None})
    return out


class Beam:
    """The laser and lens (paper §2.1–2.2); defaults are the paper's cell.

    Keyword arguments are the ``[beam]`` keys of job.toml (``power_w``, ``repetition_rate_hz``,
    ``wavelength_nm``, ``m_squared``, ``focal_length_mm``, ``beam_diameter_mm``,
    ``fluence_tolerance``, ``fluence_threshold_ratio``, ``incidence_deg``,
    ``line_width_tolerance``). The derived figures are attributes named as the keys of
    ``trimctl beam``: ``pulse_energy_uj``, ``waist_radius_um``, ``rayleigh_length_mm``,
    ``peak_fluence_j_per_cm2``, ``focus_half_length_mm``, ``spot_ratio_min``,
    ``spot_ratio_max``, ``max_incidence_for_line_width_deg``.

    ``laser_limits``: the source's limits, the ``[limits]`` keys of a laser profile
    (``crates/io/profiles/``: ``pulse_energy_uj_max``, ``average_power_w_max``,
    ``rep_rate_khz_min``, ``rep_rate_khz_max``). An operating point (``power_w``,
    ``repetition_rate_hz``, their pulse energy) outside them raises ``ValueError`` naming every
    limit broken, as ``trimctl beam`` does for ``cell.laser_profile``. Not given: not checked.
    """

    def __init__(
        self, *, laser_limits: Optional[Mapping[str, float]] = None, **settings: float
    ) -> None:
        self.settings: Dict[str, float] = dict(settings)
        self.laser_limits: Optional[Dict[str, float]] = (
            None if laser_limits is None else dict(laser_limits)
        )
        self._report: Dict[str, float] = _native.beam_report(
            _settings_json("beam", settings), _limits_json(self.laser_limits)
        )
        for key, value in self._report.items():
            setattr(self, key, value)

    def report(self) -> Dict[str, float]:
        """The derived figures as a dict (what ``trimctl beam`` prints)."""
        return dict(self._report)

    def __repr__(self) -> str:
        return f"Beam({self.settings}) -> {self._report}"


@dataclass(frozen=True)
class Layer:
    """One layer: focus point (mm), machine pose (axis → mm or degrees), galvo polylines."""

    index: int
    focus_point: np.ndarray
    pose: Dict[str, float]
    polylines: List[Tuple[int, np.ndarray]]
    """(contour id, (n, 2) galvo millimetres) per polyline: the geometry in the zone frame."""
    commands: List[np.ndarray] = field(default_factory=list)
    """Per polyline, (n, 2) mm: what the galvo is sent (height term and field correction)."""
    heights_mm: List[np.ndarray] = field(default_factory=list)
    """Per polyline, (n,) mm: each point's height above the focal plane, toward the lens."""


@dataclass(frozen=True)
class Zone:
    """One zone: origin (mm), frame (3 × 3, rows X, Y, Z in work-piece coordinates), layers."""

    id: int
    origin: np.ndarray
    frame: np.ndarray
    contours: List[int]
    max_incidence_deg: float
    max_pairwise_deg: float
    layers: List[Layer]

    @property
    def axis(self) -> np.ndarray:
        """The zone axis (the beam direction toward the lens)."""
        return self.frame[2]


@dataclass(frozen=True)
class Plan:
    """A planned job. ``to_json()`` is the Job of DESIGN.md, the same as ``trimctl plan``."""

    job: Dict[str, Any]
    table: List[Dict[str, Any]] = field(default_factory=list)
    k: Optional[int] = None
    automatic_k: Optional[bool] = None

    @property
    def zones(self) -> List[Zone]:
        zones = []
        for z in self.job["zones"]:
            layers = [
                Layer(
                    index=l["index"],
                    focus_point=np.asarray(l["focus_point"], dtype=np.float64),
                    pose=dict(l["pose"]),
                    polylines=[
                        (p["contour"], np.asarray(p["points"], dtype=np.float64).reshape(-1, 2))
                        for p in l["polylines"]
                    ],
                    commands=[
                        np.asarray(p.get("commands") or p["points"], dtype=np.float64).reshape(-1, 2)
                        for p in l["polylines"]
                    ],
                    heights_mm=[
                        np.asarray(p.get("heights_mm", []), dtype=np.float64)
                        for p in l["polylines"]
                    ],
                )
                for l in z["layers"]
            ]
            f = z["frame"]
            zones.append(
                Zone(
                    id=z["id"],
                    origin=np.asarray(z["origin"], dtype=np.float64),
                    frame=np.array([f["x"], f["y"], f["z"]], dtype=np.float64),
                    contours=list(z["contours"]),
                    max_incidence_deg=z["max_incidence_deg"],
                    max_pairwise_deg=z["max_pairwise_deg"],
                    layers=layers,
                )
            )
        return zones

    @property
    def layer_step_mm(self) -> float:
        return float(self.job["layer_step_mm"])

    @property
    def focus_half_length_mm(self) -> float:
        return float(self.job["focus_half_length_mm"])

    @property
    def validation(self) -> Dict[str, Any]:
        return dict(self.job["validation"])

    @property
    def estimate(self) -> Dict[str, Any]:
        return dict(self.job["estimate"])

    def workpiece_from_galvo(self, zone: Zone, layer: Layer, xy: np.ndarray) -> np.ndarray:
        """Maps (n, 2) galvo points of a layer back to the work-piece frame (on the focal
        plane): ``P = focus_point + x·X + y·Y``."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return layer.focus_point + xy[:, :1] * zone.frame[0] + xy[:, 1:2] * zone.frame[1]

    def galvo_to_workpiece(self, *args: Any, **kwargs: Any) -> np.ndarray:
        """Renamed :meth:`workpiece_from_galvo` (transforms read ``a_from_b``)."""
        raise AttributeError(
            "Plan.galvo_to_workpiece was renamed Plan.workpiece_from_galvo (a_from_b, as the "
            "rest of trimctl names transforms)"
        )

    def to_json(self) -> str:
        return json.dumps(self.job, indent=2)

    @classmethod
    def from_json(cls, text: str) -> "Plan":
        job = json.loads(text)
        if job.get("version") != 1:
            raise ValueError(f"job: version {job.get('version')!r} is not supported (expected 1)")
        return cls(job=job)


def _limits_json(laser_limits: Optional[Mapping[str, float]]) -> Optional[str]:
    return None if laser_limits is None else _settings_json("laser_limits", dict(laser_limits))


def _pair(name: str, value: Any) -> List[float]:
    """Two numbers (a width and a height, mm), refused naming ``name``: ``field_mm=(1,)``
    raised a bare ``IndexError``."""
    try:
        items = list(value)
    except TypeError:
        raise TypeError(f"{name}: expected two numbers (width, height), got {value!r:.60}") from None
    if len(items) != 2:
        raise ValueError(f"{name}: expected two numbers (width, height), got {len(items)}: {value!r:.60}")
    try:
        return [float(items[0]), float(items[1])]
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected two numbers (width, height), got {value!r:.60}") from None


def plan(
    path: Path,
    *,
    beam: Optional[Beam] = None,
    laser_limits: Optional[Mapping[str, float]] = None,
    max_incidence_deg: Optional[float] = None,
    layer_step_mm: Optional[float] = None,
    field_mm: Optional[Sequence[float]] = None,
    kinematics: Optional[str] = None,
    k: Optional[int] = None,
    settings: Optional[Mapping[str, Any]] = None,
    **renamed: Any,
) -> Plan:
    """Plans zones, layers, galvo polylines and machine poses for a (registered) path.

    ``settings`` takes any planner key of job.toml (``max_incidence_deg`` and the ``zoning``,
    ``layers``, ``field``, ``machine``, ``galvo`` tables). A keyword option that is given
    overrides its key (``max_incidence_deg``; ``beam`` → ``beam``; ``layer_step_mm`` →
    ``layers.step_mm``; ``field_mm`` → ``galvo.field_mm``; ``kinematics`` →
    ``machine.kinematics``; ``k`` → ``zoning.k``); one that is not given leaves the key to
    ``settings``, else to the job.toml default (5°, 100 × 100 mm, ``xyzac-trt``).
    ``settings`` itself is not changed. ``laser_limits`` (as for :class:`Beam`; default: those
    ``beam`` was made with): the beam's operating point must be within them, else
    ``ValueError`` before anything is planned. The old option names without a unit
    (``layer_step``, ``field``) raise ``TypeError`` naming the new one.
    """
    _refuse_renamed("plan", renamed, {"layer_step": "layer_step_mm", "field": "field_mm"})
    s = _kw(settings, max_incidence_deg=max_incidence_deg)
    if beam is not None:
        if not isinstance(beam, Beam):
            raise TypeError(f"beam: expected a trimctl.Beam, got {type(beam).__name__} {beam!r:.60}")
        s["beam"] = dict(beam.settings)
    if layer_step_mm is not None:
        s.setdefault("layers", {})["step_mm"] = layer_step_mm
    if k is not None:
        if isinstance(k, bool) or not isinstance(k, numbers.Integral):
            raise TypeError(f"k: expected a whole number of zones, got {type(k).__name__} {k!r:.60}")
        if k < 1:
            raise ValueError(f"k: expected a whole number of zones >= 1, got {k}")
        s.setdefault("zoning", {})["k"] = int(k)
    if field_mm is not None:
        s.setdefault("galvo", {})["field_mm"] = _pair("field_mm", field_mm)
    if kinematics is not None:
        s.setdefault("machine", {})["kinematics"] = kinematics
    if laser_limits is None and beam is not None:
        laser_limits = beam.laser_limits
    job, table, meta = _native.plan_path(path, _settings_json("plan settings", s), _limits_json(laser_limits))
    return Plan(job=job, table=table, k=meta["k"], automatic_k=meta["automatic_k"])


_POSE_KEYS = ("xyz_mm", "tilt_deg", "c_deg")


def _pose_json(k: int, pose: Mapping[str, Any]) -> str:
    """One machine pose as the JSON of a ``[part.scan_pose]`` table (numpy numbers as floats),
    refusing a pose that is not a mapping or holds a non-finite number with ``ValueError``
    naming ``poses[k]`` and the key. Unknown keys and wrong types are refused in Rust."""
    if not isinstance(pose, Mapping):
        raise ValueError(
            f"poses[{k}]: expected a mapping with the keys {', '.join(_POSE_KEYS)}, "
            f"got a {type(pose).__name__}"
        )

    def number(key: str, v: Any) -> Any:
        if isinstance(v, numbers.Real) and not isinstance(v, bool):
            if not math.isfinite(v):
                raise ValueError(f"poses[{k}].{key}: {v!r}: values must be finite")
            return float(v)
        return v

    out: Dict[str, Any] = {}
    for key, value in pose.items():
        if isinstance(value, (list, tuple, np.ndarray)):
            out[key] = [number(key, v) for v in value]
        else:
            out[key] = number(key, value)
    return json.dumps(out)


def merge_scans(
    scans: Sequence[np.ndarray],
    poses: Sequence[Mapping[str, Any]],
    *,
    settings: Optional[Mapping[str, Any]] = None,
) -> np.ndarray:
    """Merges scans of one clamped part taken at several machine poses into one cloud in the
    work-piece frame, the cloud :func:`register_path` takes (``trimctl register --scan A --scan
    B --poses poses.csv``; job.toml ``[part] scans`` and ``poses``).

    ``scans`` are ``(N_i, 3)`` float64 arrays in the scanner frame, mm. ``poses`` holds one
    machine pose per scan, in order, with the keys of job.toml's ``[part.scan_pose]``:
    ``xyz_mm`` (the X, Y, Z joint positions, mm), ``tilt_deg`` (the tilting axis: A, or B on a
    ``xyzbc-trt`` cell) and ``c_deg``; a key left out is 0. ``settings`` takes the planner keys
    of job.toml as :func:`plan` does; its ``machine`` and ``calibration`` tables carry each scan
    through the rotary axes and the scanner's pose on the head (the nominal cell without them).
    ``settings`` itself is not changed.

    Returns the ``(sum N_i, 3)`` merged points, the scans' points in order. A scan of another
    shape or dtype, an empty scan, a non-finite value, an unknown pose key or a count of poses
    other than of scans raises ``ValueError`` naming it (``scans[1]``, ``poses[0].c_deg``).
    """
    if isinstance(scans, np.ndarray):
        raise ValueError(
            f"scans: expected a sequence of (N, 3) arrays, got one array of shape {scans.shape}"
        )
    if isinstance(poses, Mapping):
        raise ValueError("poses: expected a sequence of poses (one mapping per scan), got one")
    pose_json = [_pose_json(k, p) for k, p in enumerate(poses)]
    s = _kw(settings)
    return _native.merge_scans(list(scans), pose_json, _settings_json("settings", s))


@dataclass(frozen=True)
class ScanPoses:
    """A poses.csv file (:func:`read_poses`): the machine pose each scan was taken at.

    ``kinematics`` is the cell its header implies (``"xyzac-trt"`` for an ``a`` column,
    ``"xyzbc-trt"`` for ``b``); ``rows`` holds ``(scan file name, pose)`` in file order, each
    pose a mapping with the keys of job.toml's ``[part.scan_pose]`` (``xyz_mm``, ``tilt_deg``,
    ``c_deg``), as :func:`merge_scans` takes it.
    """

    path: str
    kinematics: str
    rows: List[Tuple[str, Dict[str, Any]]]

    def pose_of(self, scan: Any) -> Dict[str, Any]:
        """The pose of the scan file ``scan`` (a path; its file name names its row, and
        ``read_poses`` refuses a file naming one scan twice, as ``trimctl register --poses``
        does). A file without a row raises ``KeyError`` naming it and the poses file."""
        name = os.path.basename(os.fspath(scan))
        for row_name, pose in self.rows:
            if row_name == name:
                return copy.deepcopy(pose)
        raise KeyError(f"{os.fspath(scan)}: no pose for scan {name} in {self.path}")


def read_poses(path: Any) -> ScanPoses:
    """Reads poses.csv: header ``scan,x,y,z,a,c`` (``b`` for ``a`` on a B/C cell), one row per
    scan file, named by its file name; X, Y, Z joint positions in mm, the rotary axes in
    degrees; blank and ``#`` lines skipped. The format ``trimctl register --poses``,
    ``run``'s ``[part] poses`` and ``calibrate cell`` read.

    A missing or empty file, a wrong header, a row of another column count or a value that is
    not a finite number raises :class:`FileFormatError` naming the file and the line.
    """
    kinematics, rows = _native.read_poses(os.fspath(path))
    return ScanPoses(
        path=os.fspath(path),
        kinematics=kinematics,
        rows=[
            (scan, {"xyz_mm": list(xyz), "tilt_deg": tilt, "c_deg": c})
            for scan, xyz, tilt, c in rows
        ],
    )


def merge_scan_files(
    files: Sequence[Any],
    poses: Any,
    *,
    settings: Optional[Mapping[str, Any]] = None,
) -> np.ndarray:
    """:func:`merge_scans` from files: reads the scan files ``files`` (PLY/PCD/XYZ, scanner
    frame, mm) and carries each into the work-piece frame at the pose its file name has in the
    poses file ``poses`` (:func:`read_poses`), as ``trimctl register --scan A --scan B --poses
    poses.csv`` does. ``settings`` as for :func:`merge_scans`; the poses file's header must
    name the cell of its ``machine`` table (``a`` for ``xyzac-trt``, the default; ``b`` for
    ``xyzbc-trt``).

    Returns the ``(sum N_i, 3)`` merged points, files in order. A file without a row in the
    poses file raises ``ValueError`` naming both before any scan is read; an unreadable or
    malformed scan or poses file raises :class:`FileFormatError` naming the file (and the
    line), a header of another cell ``ValueError``.
    """
    if isinstance(files, (str, bytes, os.PathLike)):
        raise ValueError(
            f"files: expected a sequence of scan files, got one path {os.fspath(files)!r}"
        )
    paths = [os.fspath(f) for f in files]
    s = _kw(settings)
    return _native.merge_scan_files(paths, os.fspath(poses), _settings_json("settings", s))


@dataclass(frozen=True)
class Registration:
    """A registered path, its per-contour quality report and the coarse ``scan_from_cad``."""

    path: Path
    report: Dict[str, Any]
    scan_from_cad: np.ndarray
    quality: List[ContourQuality] = field(default_factory=list)
    """Per-contour quality, typed (built in Rust), in path order."""

    @property
    def contours(self) -> List[Dict[str, Any]]:
        """Per-contour quality as the report's dicts (see :attr:`quality` for typed ones)."""
        return list(self.report["contours"])

    @property
    def predicted_max_error_um(self) -> Dict[int, float]:
        """Each contour's predicted bound on its largest cross-edge error, µm, by contour id."""
        return {int(c["id"]): float(c["predicted_max_error_um"]) for c in self.report["contours"]}

    @property
    def untrustworthy(self) -> List[int]:
        return [c["id"] for c in self.report["contours"] if not c["trustworthy"]]

    @property
    def refused(self) -> Optional[str]:
        """Why the part as a whole cannot be trusted (every contour is then flagged
        ``part_refused``), or ``None``."""
        return self.report["global"].get("refused")

    @property
    def in_doubt(self) -> Optional[str]:
        """Why the part is in doubt (a strip's edge, or a hole's rim slid, off the scan by more
        than the tolerance: ``ContourQuality.scan_slide_gap_um``; a rim the scan reads larger
        all round, not slid, is flagged ``edge_off_scan`` but puts no part in doubt; or more
        than ``max_untrusted_fraction`` of its contours flagged), or ``None``. In a part in doubt
        every contour whose bound at 1.5 sigma (``ContourQuality.doubt_bound_um``; the
        reported bound is at 2.1 sigma) exceeds ``quality.doubt_bound_fraction`` of the
        tolerance is flagged ``part_in_doubt``, and so is every strip that shares an end with
        a strip then untrusted (a slide along an edge carries over the shared end; the reason
        names them); the others stay trusted."""
        return self.report["global"].get("in_doubt")

    @property
    def edges_in_doubt(self) -> Optional[str]:
        """Why some edges of a part that is not in doubt are (more than half of the strips
        joined end to end along an edge off by more than 4/3 of the tolerance), or ``None``.
        Each other strip of such an edge that joins one of those and whose bound at 1.5 sigma
        (``ContourQuality.doubt_bound_um``) exceeds ``quality.doubt_bound_fraction`` of the
        tolerance is flagged ``edge_in_doubt``."""
        return self.report["global"].get("edges_in_doubt")

    @property
    def region_in_doubt(self) -> Optional[str]:
        """Why a stretch of a part that is not in doubt is (at least five contours off by
        more than 1.5 times the tolerance by their bounds), or ``None``. Each other contour
        reaching into their extent along the part's long axis (widened by 5 mm) whose bound at
        1.5 sigma (``ContourQuality.doubt_bound_um``) exceeds two thirds of the tolerance is
        flagged ``region_in_doubt``, and so is every strip, whatever its bound, that shares an
        end with a strip untrusted there (a slide along an edge carries over the shared end)."""
        return self.report["global"].get("region_in_doubt")

    @property
    def slide_retry(self) -> Optional[Dict[str, Any]]:
        """What the retry after a refusal did (``coarse.slide_retry``), or ``None`` when the
        first registration was not refused: ``first_refusal`` (its reason),
        ``first_coarse_rmse_mm``, ``shift_mm`` (the start along the part's long axis the
        retry's best coarse fit came from; 0 when the captured pose fitted best again) and
        ``taken`` (the retry is this registration; otherwise the refused first one is)."""
        return self.report["global"].get("slide_retry")

    @property
    def expected_over_p95(self) -> Optional[float]:
        """How many of the trusted contours are expected to lie farther across than the
        cross-edge P95 limit (``report["global"]["p95_limit_um"]``, 12 µm of a 30 µm tolerance):
        the sum of their ``ContourQuality.p95_risk``, ``None`` without a posterior (global mode).
        ``settings={"quality": {"max_p95_risk": 0.05}}`` flags ``p95_risk`` on every contour whose
        chance exceeds 5 %."""
        return self.report["global"].get("expected_over_p95")


def register_path(
    cad: np.ndarray,
    scan: np.ndarray,
    path: Path,
    *,
    cad_normals: np.ndarray,
    scan_normals: Optional[np.ndarray] = None,
    init: Optional[np.ndarray] = None,
    mode: Optional[str] = None,
    settings: Optional[Mapping[str, Any]] = None,
) -> Registration:
    """Registers the CAM ``path`` (CAD frame) onto the ``scan``: coarse similarity from the
    fixture pose ``init`` (4 × 4 ``scan_from_cad``, default identity), then the deformation
    field. ``cad`` are CAD points (N, 3) with outward ``cad_normals``. ``settings`` takes the
    ``[register]`` keys of job.toml; ``mode``, when given, overrides ``settings["mode"]``
    (default ``"regional"``). ``settings`` itself is not changed.
    """
    s = _kw(settings, mode=mode)
    registered, report, scan_from_cad, quality = _native.register_path(
        cad, cad_normals, scan, path, init, _settings_json("settings", s), scan_normals
    )
    return Registration(
        path=registered, report=report, scan_from_cad=scan_from_cad, quality=quality
    )


@dataclass(frozen=True)
class DemoCase:
    """A synthetic ceramic-core case: CAD (mesh and points with normals), template path, a scan
    of the deformed re-posed part, and the ground-truth registered path."""

    cad_points: np.ndarray
    cad_normals: np.ndarray
    cad_vertices: np.ndarray
    cad_triangles: np.ndarray
    path: Path
    scan: np.ndarray
    truth: Path
    scan_from_cad_nominal: np.ndarray
    scan_from_cad_true: np.ndarray


def synth(seed: int = 1, **params: Any) -> DemoCase:
    """Generates the demo case (``trimctl synth``). Options: ``sag_mm``, ``twist_deg``,
    ``scale_range``, ``noise_mm``, ``scan_points``, ``cad_points``, ``pose_deg``, ``pose_mm``,
    ``outlier_fraction``, ``dropouts``, ``scanner_tilt_deg``, ``scanner_views`` (fixed views of
    the machine-mounted scanner, 1–4; default 1, the demo cell of ``trimctl run`` uses 3),
    ``burr_fraction``, ``pressing_tilt_deg``, ``tip_curl_mm``, ``shrink_gradient`` (the change of
    shrinkage along the span, end to end: a density gradient), ``path_spacing_mm``,
    ``mesh_step_mm``."""
    d = _native.synth_case(_settings_json("synth", {"seed": seed, **params}))
    return DemoCase(
        cad_points=d["cad_points"],
        cad_normals=d["cad_normals"],
        cad_vertices=d["cad_vertices"],
        cad_triangles=d["cad_triangles"].astype(np.int64),
        path=d["path"],
        scan=d["scan"],
        truth=d["truth"],
        scan_from_cad_nominal=d["scan_from_cad_nominal"],
        scan_from_cad_true=d["scan_from_cad_true"],
    )


def hatch(
    points: np.ndarray,
    boundary: np.ndarray,
    *,
    pitch_mm: Optional[float] = None,
    spot_diameter_mm: Optional[float] = None,
    overlap: Optional[float] = None,
    normals: Optional[np.ndarray] = None,
    angle_deg: Optional[float] = None,
    method: Optional[str] = None,
    step_mm: Optional[float] = None,
    chord_tolerance_mm: Optional[float] = None,
    outline: Optional[bool] = None,
    settings: Optional[Mapping[str, Any]] = None,
    **renamed: Any,
) -> Path:
    """Equal-spacing hatch tracks on a scanned surface (``trimctl hatch``; the cladding paper's
    method done better).

    ``points`` (N, 3) is the surface scan in mm, ``normals`` (N, 3) its normals if known (else
    they come from the surface fit); ``boundary`` (M, 3) a closed polyline lying on the surface
    (a polygon: the last row may repeat the first, else the closing edge is implied). The track
    pitch is ``pitch_mm``, or ``spot_diameter_mm × (1 − overlap)``. ``angle_deg`` turns the hatch direction in the patch's
    best-fit plane from world X; ``method`` is ``"geodesic"`` (default) or ``"slab"`` (the
    paper's); points along a track are ``step_mm`` apart (default: the pitch), or placed by
    ``chord_tolerance_mm`` for vector marking; ``outline=False`` leaves out the track along the
    boundary. ``settings`` takes the same keys as job.toml's ``[[hatch]]`` (``pitch_mm``,
    ``angle_deg``, ``method``, ``step_mm``, ``chord_tolerance_mm``, ``outline``, ``grid_mm``); a
    keyword that is given overrides its key.

    Returns a :class:`Path`: one contour per track, in serpentine order (the outline last), each
    point's feature vector the unit surface normal. Raises ``ValueError`` for bad input (naming
    it) and ``PlanningError`` when the region cannot be hatched. The old option names without a
    unit (``pitch``, ``spot_diameter``, ``step``, ``chord_tolerance``) raise ``TypeError`` naming
    the new one.
    """
    _refuse_renamed(
        "hatch",
        renamed,
        {
            "pitch": "pitch_mm",
            "spot_diameter": "spot_diameter_mm",
            "step": "step_mm",
            "chord_tolerance": "chord_tolerance_mm",
        },
    )
    if pitch_mm is not None and (spot_diameter_mm is not None or overlap is not None):
        raise ValueError("pitch_mm: give either pitch_mm or spot_diameter_mm and overlap, not both")
    if (spot_diameter_mm is None) != (overlap is None):
        raise ValueError(
            "spot_diameter_mm, overlap: give both (pitch = spot_diameter_mm × (1 − overlap))"
        )
    spot = None if spot_diameter_mm is None else (float(spot_diameter_mm), float(overlap))
    s = _kw(
        settings,
        pitch_mm=pitch_mm,
        angle_deg=angle_deg,
        method=method,
        step_mm=step_mm,
        chord_tolerance_mm=chord_tolerance_mm,
        outline=outline,
    )
    pts = np.ascontiguousarray(points, dtype=np.float64)
    b = np.ascontiguousarray(boundary, dtype=np.float64)
    n = None if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
    return _native.hatch_surface(pts, b, _settings_json("hatch settings", s), n, spot)
