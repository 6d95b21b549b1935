"""Bad settings and inputs from Python get a ValueError (or the module's error) naming what is at
fault, never an abort, a hang or an InternalError: NaN in a setting, numpy numbers, a settings
value that is not a mapping, a field too fine for the part, a path in other units than the CAD,
an iteration count of millions, Umeyama on points that coincide or overflow."""

import numpy as np
import pytest

import trimctl


@pytest.fixture(scope="module")
def case():
    return trimctl.synth(seed=4, scan_points=20_000, cad_points=20_000)


def test_a_nan_setting_is_refused_naming_its_key(case):
    with pytest.raises(ValueError, match=r"layers\.step_mm = nan: must be a finite number"):
        trimctl.plan(case.path, settings={"layers": {"step_mm": float("nan")}})
    with pytest.raises(ValueError, match=r"power_w = inf"):
        trimctl.Beam(power_w=float("inf"))
    with pytest.raises(ValueError, match=r"expected a mapping"):
        trimctl.plan(case.path, settings="layers.step_mm=1")


def test_numpy_numbers_are_taken_as_numbers(case):
    plain = trimctl.plan(case.path, max_incidence_deg=5.0, settings={"zoning": {"restarts": 3}})
    numpy = trimctl.plan(
        case.path, max_incidence_deg=np.float32(5.0), settings={"zoning": {"restarts": np.int64(3)}}
    )
    assert numpy.k == plain.k
    assert numpy.to_json() == plain.to_json()


def test_a_field_too_fine_and_endless_iterations_are_refused_by_key(case):
    with pytest.raises(ValueError, match=r"field\.spacing_mm.*use at least"):
        trimctl.register_path(
            case.cad_points, case.scan, case.path, cad_normals=case.cad_normals,
            init=case.scan_from_cad_nominal, settings={"field": {"spacing_mm": 1.0}},
        )
    with pytest.raises(ValueError, match=r"field\.iterations"):
        trimctl.register_path(
            case.cad_points, case.scan, case.path, cad_normals=case.cad_normals,
            init=case.scan_from_cad_nominal, settings={"field": {"iterations": 10**6}},
        )


def test_a_path_in_other_units_than_the_cad_names_the_contour(case):
    p = case.path
    micrometres = trimctl.Path(p.ids, p.points * 1000.0, p.features)
    with pytest.raises(trimctl.TrimError, match=r"contour .*outside the CAD's bounding box"):
        trimctl.register_path(
            case.cad_points, case.scan, micrometres, cad_normals=case.cad_normals,
            init=case.scan_from_cad_nominal,
        )


def test_umeyama_on_coincident_or_overflowing_points_is_an_error():
    rng = np.random.default_rng(3)
    a = rng.uniform(-10, 10, (50, 3))
    with pytest.raises(trimctl.TrimError, match="coincide") as e:
        trimctl.umeyama(a, np.zeros((50, 3)))
    assert not isinstance(e.value, trimctl.InternalError), e.value
    with pytest.raises((ValueError, trimctl.TrimError)) as e:
        trimctl.umeyama(a, a * 1e300)
    assert not isinstance(e.value, trimctl.InternalError), e.value
