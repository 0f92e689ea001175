"""CRF file format and the monotone fit from integrating-sphere data."""

import numpy as np
import pytest

from controller.errors import InputError
from controller.imaging.crf import Crf
from controller.imaging.crf_io import fit_crf_file as fit_crf
from simplant.devices.sensor import SensorModel, knee_response


def sphere_csv(path, sensors, rng, noise=0.3):
    """Integrating-sphere data from known sensors: 40 exposure values each, up to saturation."""
    lines = ["sensor,exposure_value,pixel_mean"]
    for name, s in sensors:
        for x in np.linspace(0.0, 1.3 * s.span / s.gain, 40):
            z = min(float(s.expected_value(x, 1.0)) + rng.normal(0, noise), 255.0)
            lines.append(f"{name},{x:.6f},{z:.4f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_fit_recovers_known_response(tmp_path):
    s1 = SensorModel(response=knee_response(0.15))
    s2 = SensorModel(response=knee_response(0.25), gain=1.03)
    csv = sphere_csv(tmp_path / "sphere.csv", [("ccd1", s1), ("ccd2", s2)], np.random.default_rng(0))
    crf, fits = fit_crf(csv)
    assert [s.name for s in crf.sensors] == ["ccd1", "ccd2"]
    for k, s in enumerate((s1, s2)):
        true = s.inverse_response()
        got = crf.inverse(k)
        z = np.arange(30, 250)
        assert np.max(np.abs(got[z] - true[z]) / true[z]) < 0.02
        assert np.all(np.diff(got) >= 0) and got[0] == 0.0
        assert 0.0 < fits[k].uncertainty_pct < 3.0
        assert fits[k].points_saturated > 0           # points above saturation were dropped
        assert fits[k].dark_level == pytest.approx(8.0, abs=0.5)


def test_save_load_round_trip(tmp_path):
    crf = Crf.from_tables([SensorModel(response=knee_response(0.2)).inverse_response(),
                           np.arange(256.0)])
    crf.save(tmp_path / "crf.yaml")
    back = Crf.load(tmp_path / "crf.yaml")
    assert np.allclose(back.inverse(0), crf.inverse(0), atol=1e-8)
    assert np.allclose(back.inverse(1), np.arange(256.0))
    assert back.sensors[0].name == "ccd1" and back.bit_depth == 8


def test_linear_default():
    assert np.array_equal(Crf.linear(8).inverse(0), np.arange(256.0))
    assert Crf.linear(8, dark_offset=8).inverse(1)[20] == 12.0


@pytest.mark.parametrize("text, msg", [
    ("sensors: 3", "sensors: required key"),
    ("sensors:\n  - {name: a, bit_depth: 8}\n  - {name: b, bit_depth: 8}",
     r"sensors\[0\].inverse_response: required"),
    ("sensors:\n  - {name: a, bit_depth: 8, inverse_response: [1, 2]}\n"
     "  - {name: b, bit_depth: 8, inverse_response: [1, 2]}", "needs 256 numbers"),
    ("sensors:\n  - {name: a, bit_depth: 1, inverse_response: [2, 1]}\n"
     "  - {name: b, bit_depth: 1, inverse_response: [0, 1]}",
     r"sensors\[0\].inverse_response\[1\]: must be non-decreasing"),
    ("sensors:\n  - {name: a, bit_depth: 1, inverse_response: [0, 1], colour: red}\n",
     r"sensors\[0\].colour: unknown key"),
    ("sensors: [", "invalid YAML"),
])
def test_bad_crf_files_name_the_key(tmp_path, text, msg):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(InputError, match=msg):
        Crf.load(p)


@pytest.mark.parametrize("text, msg", [
    ("a,b,c\n1,2,3\n", "header must contain"),
    ("sensor,exposure_value,pixel_mean\nccd1,x,3\n", "line 2"),
    ("sensor,exposure_value,pixel_mean\nccd1,1,3\n", "exactly 2 sensors"),
])
def test_bad_sphere_csv(tmp_path, text, msg):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=msg):
        fit_crf(p)


def test_pure_fit_from_arrays_equals_the_file_fit(tmp_path):
    from controller.imaging.crf import fit_crf as fit_arrays
    from controller.imaging.crf_io import read_sphere_csv

    s1, s2 = SensorModel(response=knee_response(0.15)), SensorModel(response=knee_response(0.25))
    csv = sphere_csv(tmp_path / "sphere.csv", [("ccd1", s1), ("ccd2", s2)], np.random.default_rng(1))
    from_file, _ = fit_crf(csv)
    from_arrays, fits = fit_arrays(read_sphere_csv(csv), source="sphere")
    for k in (0, 1):
        np.testing.assert_array_equal(from_arrays.inverse(k), from_file.inverse(k))
    x, z = np.array([1.0, 2.0]), np.array([10.0, 20.0])
    with pytest.raises(InputError, match="^sphere: sensor 'a': needs at least"):
        fit_arrays({"a": (x, z), "b": (x, z)}, source="sphere")


def test_crf_load_and_save_are_the_io_module(tmp_path):
    from controller.imaging.crf_io import load_crf, save_crf

    crf = Crf.linear(8, 8.0)
    save_crf(crf, tmp_path / "a.yaml")
    crf.save(tmp_path / "b.yaml")
    assert (tmp_path / "a.yaml").read_text() == (tmp_path / "b.yaml").read_text()
    np.testing.assert_array_equal(Crf.load(tmp_path / "a.yaml").inverse(1),
                                  load_crf(tmp_path / "b.yaml").inverse(1))
