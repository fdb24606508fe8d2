import numpy as np
import pytest

import model as m
from model import merl
from model.checks import check_reciprocity, random_hemisphere
from model.geometry import from_half_diff


@pytest.fixture(scope="module")
def table():
    return merl.MerlTable.from_model(m.CookTorrance(alpha=0.3, eta=(0.2, 0.9, 1.1), k=(3.9, 2.4, 2.2), rho_d=0.1))


def test_bin_centres_reproduce_the_model(table):
    ct = m.CookTorrance(alpha=0.3, eta=(0.2, 0.9, 1.1), k=(3.9, 2.4, 2.2), rho_d=0.1)
    th, td, pd = (a[::7, ::5, ::11].reshape(-1) for a in merl.bin_centers())
    wi, wo = from_half_diff(th, 0.4, td, pd)
    assert np.allclose(table.eval(wi, wo), ct.eval(wi, wo), rtol=1e-12)


def test_file_round_trip_is_bit_exact_up_to_the_stored_scale(table, tmp_path):
    path = tmp_path / "ct.binary"
    merl.write_merl(table, path)
    assert path.stat().st_size == merl.FILE_BYTES
    back = merl.read_merl(path)
    assert np.allclose(back.values, table.values, rtol=1e-15)
    header = np.frombuffer(path.read_bytes()[:12], dtype="<i4")
    assert header.tolist() == [90, 90, 180]


def test_missing_data_is_flagged_and_evaluates_to_zero(table, tmp_path):
    values = table.values.copy()
    values[:, 0, :, :] = np.nan  # no data for the first theta_h bin
    holey = merl.MerlTable(values)
    path = tmp_path / "holey.binary"
    merl.write_merl(holey, path)
    raw = np.frombuffer(path.read_bytes()[12:], dtype="<f8")
    assert raw[0] == -1.0
    back = merl.read_merl(path)
    wi = np.array([0.0, 0.0, 1.0])
    assert not back.has_data(wi, wi)
    assert np.all(back.eval(wi, wi) == 0)
    oblique = np.array([0.6, 0.0, 0.8])
    assert not back.has_data(oblique, np.array([-0.6, 0.0, 0.8]))  # mirror pair: theta_h = 0 too
    assert back.has_data(oblique, np.array([0.0, 0.6, 0.8]))


def test_table_is_reciprocal_and_usable_by_checks(table):
    assert check_reciprocity(table, n=2000, tolerance=0.0).passed


def test_lookup_shapes_and_horizon(table):
    rng = np.random.default_rng(0)
    wi, wo = random_hemisphere(10, rng), random_hemisphere(10, rng)
    assert table.eval(wi, wo).shape == (10, 3)
    assert np.all(table.eval(wi, -wo) == 0)


@pytest.mark.parametrize(
    "content,message",
    [
        (b"", "too short"),
        (np.array([90, 90, 90], dtype="<i4").tobytes(), "header dimensions (90, 90, 90)"),
        (np.array([90, 90, 180], dtype="<i4").tobytes() + b"\0" * 80, "expected 34992012"),
    ],
)
def test_corrupt_files_give_clear_errors(tmp_path, content, message):
    path = tmp_path / "bad.binary"
    path.write_bytes(content)
    with pytest.raises(merl.MerlFormatError) as err:
        merl.read_merl(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="MERL file not found"):
        merl.read_merl(tmp_path / "nope.binary")


def test_wrong_shape_values():
    with pytest.raises(merl.MerlFormatError, match="shape"):
        merl.MerlTable(np.zeros((3, 10, 10, 10)))
