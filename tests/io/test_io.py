"""Data files: CSV/NPZ readers with located error messages, writers, round trips."""

import numpy as np
import pytest

import bayescal as bc
from bayescal.io.data import (
    InputError,
    check_pixels_in_image,
    check_projection_domain,
    load_calibration_data,
    load_laser_data,
    load_pixels,
    parse_image_size,
    read_json,
    read_table,
    write_calibration_npz,
    write_json,
    write_laser_csv,
    write_laser_npz,
)
from bayescal.scene.simulate import SIGMA_SCENE_FLOOR_MM

GOOD = "u,v,x,y,z\n450.0,300.0,1000.0,0.0,377.0\n400.0,250.0,0.0,1000.0,377.0\n"


def _write(tmp_path, text, name="laser.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def ds():
    return bc.simulate_room(range_mm=1000, n_points=25, sigma_px=0.3, approx_error=0.05, rng=3)


def test_csv_reads_columns_any_order_and_case(tmp_path):
    p = _write(tmp_path, "Z, y ,X,v,U\n1,2,3,4,5\n")
    data = load_laser_data(p)
    np.testing.assert_array_equal(data.pixels, [[5.0, 4.0]])
    np.testing.assert_array_equal(data.approx_points, [[3.0, 2.0, 1.0]])
    assert data.sigma_scene is None and data.sigma_px is None


def test_line_numbers_count_comments_and_blank_lines(tmp_path):
    p = _write(tmp_path, "# a comment\n\nu,v,x,y,z\n1,2,3,4,5\n# mid\n1,2,oops,4,5\n")
    with pytest.raises(InputError, match=r"laser.csv, line 6, column 'x': could not read "
                                         r"'oops' as a number") as exc:
        load_laser_data(p)
    assert (exc.value.line, exc.value.column) == (6, "x")


@pytest.mark.parametrize("text, match", [
    ("", r"the file is empty; expected a header line"),
    ("u,v,x,y,z\n", r"no data lines"),
    ("u,v,x,y\n1,2,3,4\n", r"line 1: missing column\(s\) 'z'.*header has 'u', 'v', 'x', 'y'"),
    ("u_px,v,x,y,z\n1,2,3,4,5\n", r"missing column\(s\) 'u'"),
    ("u,v,x,y,z\n1,2,nan,4,5\n", r"line 2, column 'x': NaN is not allowed"),
    ("u,v,x,y,z\n1,2,3,inf,5\n", r"line 2, column 'y': 'inf' is not allowed"),
    ("u,v,x,y,z\n1,2,3,4,\n", r"line 2, column 'z': empty cell"),
    ("u,v,x,y,z\n1,2,3,4,5\n1,2,3,4\n", r"line 3: 4 fields, expected 5"),
    ("u,v,u,x,y,z\n1,2,3,4,5,6\n", r"column 'u' appears twice"),
    ("u,v,x,y,z,sigma_x\n1,2,3,4,5,-1\n",
     r"column 'sigma_x': '-1' is not a valid standard deviation; expected a positive number in "
     r"mm"),
    ("u,v,x,y,z,sigma_px\n1,2,3,4,5,-1\n",
     r"column 'sigma_px': '-1' is not a valid standard deviation; expected a positive number in "
     r"px"),
    ("u,v,x,y,z,sigma_x\n1,2,3,4,5,nan\n", r"column 'sigma_x': NaN is not allowed"),
    ("u,v,x,y,z,sigma_px\n1,2,3,4,5,0.1\n1,2,3,4,5,0.2\n",
     r"line 3, column 'sigma_px': sigma_px = 0.2 differs from the first value 0.1"),
])
def test_bad_csv_names_file_line_column(tmp_path, text, match):
    p = _write(tmp_path, text)
    with pytest.raises(InputError, match=match):
        load_laser_data(p)


def test_a_missing_column_is_not_also_listed_as_optional(tmp_path):
    with pytest.raises(InputError) as err:
        load_laser_data(_write(tmp_path, "u,v,x,y\n1,2,3,4\n"))
    msg = str(err.value)
    assert "expected u, v, x, y, z (optional: sigma_x" in msg
    assert "'x'" not in msg.split("optional:")[1] and ", z," not in msg.split("optional:")[1]


def test_npz_sds_say_their_unit(tmp_path):
    np.savez(tmp_path / "t.npz", pixels=np.zeros((2, 2)), approx_points=np.ones((2, 3)),
             sigma_x=np.array([1.0, -2.0]))
    with pytest.raises(InputError, match=r"sigma_x.*at least 1e-09 mm"):
        load_laser_data(tmp_path / "t.npz")


def test_sds_of_a_coordinate_of_zero_are_read_as_known(tmp_path, capsys):
    # simulate_room's relative errors times a coordinate that rounds to 6e-17 mm give sds of
    # ~1e-15 mm: the library fits them; a file holding them is read with the floor, said
    p = _write(tmp_path, "u,v,x,y,z,sigma_x,sigma_y\n1,2,3,4,5,3.9e-15,7\n1,2,3,4,5,8,9\n")
    d = load_laser_data(p)
    np.testing.assert_array_equal(d.sigma_scene[:, :2], [[1e-9, 7], [8, 9]])
    err = capsys.readouterr().err
    assert "below 1e-09 on line(s) 2 (sigma_x)" in err and "read as 1e-09" in err
    np.savez(tmp_path / "t.npz", pixels=np.zeros((2, 2)), approx_points=np.ones((2, 3)),
             sigma_x=np.array([1.0, 3.9e-15]))
    assert load_laser_data(tmp_path / "t.npz").sigma_scene[1, 0] == 1e-9
    assert "array 'sigma_x': 1 standard deviation(s) below 1e-09 (index 1)" in \
        capsys.readouterr().err


def test_missing_file_and_not_utf8(tmp_path):
    with pytest.raises(InputError, match=r"nope.csv: no such file"):
        load_laser_data(tmp_path / "nope.csv")
    p = tmp_path / "bin.csv"
    p.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError, match=r"not a UTF-8 text file"):
        load_laser_data(p)


def test_sigma_columns_empty_or_inf_mean_no_information(tmp_path):
    p = _write(tmp_path, "u,v,x,y,z,sigma_x,sigma_z,sigma_px\n1,2,3,4,5,10,,0.5\n"
                         "1,2,3,4,5,inf,7,\n")
    d = load_laser_data(p)
    np.testing.assert_array_equal(d.sigma_scene, [[10, np.inf, np.inf], [np.inf, np.inf, 7]])
    assert d.sigma_px == 0.5


def test_unknown_columns_are_ignored_with_a_warning(tmp_path, capsys):
    d = load_laser_data(_write(tmp_path, "id,u,v,x,y,z,sigma_xx\n7,1,2,3,4,5,9\n"))
    assert d.sigma_scene is None
    assert "ignoring column(s) id, sigma_xx" in capsys.readouterr().err


def test_two_files_must_have_the_same_number_of_rows(tmp_path):
    pix = _write(tmp_path, "u,v\n1,2\n3,4\n5,6\n", "pix.csv")
    pts = _write(tmp_path, "x,y,z\n1,2,3\n4,5,6\n", "pts.csv")
    with pytest.raises(InputError, match=r"pix.csv has 3 points \(u, v\) but .*pts.csv has 2"):
        load_laser_data(pix, pts)
    pts.write_text("x,y,z,sigma_y\n1,2,3,4\n4,5,6,\n7,8,9,1\n")
    d = load_laser_data(pix, pts)
    assert d.approx_points.shape == (3, 3) and d.sigma_scene[1, 1] == np.inf
    assert [p.name for p in d.paths] == ["pix.csv", "pts.csv"]


def _floored(ds):
    """The sds as ``bayescal simulate`` writes them: a point on an axis has an sd of ~1e-14
    mm in ``simulate_room``, which the readers refuse (below 1e-9)."""
    return np.maximum(ds.sigma_scene, SIGMA_SCENE_FLOOR_MM)


def test_csv_round_trip_is_exact(tmp_path, ds):
    p = write_laser_csv(tmp_path / "l.csv", ds.pixels, ds.approx_points,
                        sigma_scene=_floored(ds), sigma_px=ds.sigma_px,
                        header_comment="two\nlines")
    d = load_laser_data(p)
    np.testing.assert_array_equal(d.pixels, ds.pixels)
    np.testing.assert_array_equal(d.approx_points, ds.approx_points)
    np.testing.assert_array_equal(d.sigma_scene, _floored(ds))   # z is inf (fig9)
    assert d.sigma_px == ds.sigma_px
    assert d.pixel_table.lines[0] == 4        # two comment lines, then the header


def test_npz_stacked_and_per_column_arrays(tmp_path, ds):
    p = write_laser_npz(tmp_path / "l.npz", ds.pixels, ds.approx_points,
                        sigma_scene=_floored(ds), sigma_px=ds.sigma_px)
    d = load_laser_data(p)
    np.testing.assert_array_equal(d.pixels, ds.pixels)
    np.testing.assert_array_equal(d.sigma_scene, _floored(ds))
    assert d.sigma_px == ds.sigma_px
    q = tmp_path / "cols.npz"
    np.savez(q, u=ds.pixels[:, 0], v=ds.pixels[:, 1], x=ds.points[:, 0], y=ds.points[:, 1],
             z=ds.points[:, 2])
    np.testing.assert_array_equal(load_laser_data(q).approx_points, ds.points)


@pytest.mark.parametrize("arrays, match", [
    ({"pixels": np.zeros((3, 2))}, r"missing array\(s\) 'x', 'y', 'z'"),
    ({"pixels": np.zeros((3, 3)), "approx_points": np.ones((3, 3))},
     r"array 'pixels': shape \(3, 3\), expected \(N, 2\)"),
    ({"u": [1.0, 2.0], "v": [1.0, np.nan], "x": [1.0, 1], "y": [1.0, 1], "z": [1.0, 1]},
     r"array 'v', index 1: nan is not allowed"),
    ({"u": [1.0, 2.0], "v": [1.0, 2.0], "x": [1.0], "y": [1.0, 1], "z": [1.0, 1]},
     r"array '.': 2 entries but 'x' has 1|array 'x': 1 entries"),
])
def test_bad_npz(tmp_path, arrays, match):
    p = tmp_path / "bad.npz"
    np.savez(p, **arrays)
    with pytest.raises(InputError, match=match):
        load_laser_data(p)


def test_corrupt_npz(tmp_path):
    p = _write(tmp_path, "not a zip", "bad.npz")
    with pytest.raises(InputError, match=r"bad.npz: could not read as an NPZ archive"):
        load_laser_data(p)


def test_pixels_outside_the_image(tmp_path):
    p = _write(tmp_path, "u,v\n400,300\n-60,300\n860,-80\n")
    pix, table = load_pixels(p)
    check_pixels_in_image(pix, table, image_size=(800, 600), margin=100)
    with pytest.raises(InputError, match=r"line 3, column 'u': pixel u = -60 is outside the "
                                         r"image; expected -50 <= u <= 850 .*\(2 such rows"):
        check_pixels_in_image(pix, table, image_size=(800, 600), margin=50)


def test_points_outside_the_projection_domain(tmp_path):
    p = _write(tmp_path, "u,v,x,y,z\n1,2,1000,0,300\n1,2,0,0,500\n")
    d = load_laser_data(p)
    with pytest.raises(InputError, match=r"line 3, column 'x, y, z': point \(0, 0, 500\) mm "
                                         r"is outside the projection domain.*xi\*r - z = 0"):
        check_projection_domain(d.approx_points, d.point_table, bc.SensorParams.paper())
    # with xi = 0.5 the domain excludes a cone around +z: (1000, 0, 300) is outside it too
    narrow = bc.SensorParams.paper().replace(xi=0.2)
    with pytest.raises(InputError, match=r"line 2.*\(2 such rows in all\)"):
        check_projection_domain(d.approx_points, d.point_table, narrow)


def test_calibration_npz_round_trip_and_unknown_truth(tmp_path, ds):
    cal = ds.calibration
    p = write_calibration_npz(tmp_path / "c.npz", cal)
    back = load_calibration_data(p)
    for f in ("grid_points", "grid_pixels", "grid_plane", "laser_pixels", "laser_plane",
              "angles"):
        np.testing.assert_array_equal(getattr(back, f), getattr(cal, f))
    q = tmp_path / "real.npz"
    np.savez(q, grid_points=cal.grid_points, grid_pixels=cal.grid_pixels,
             grid_plane=cal.grid_plane, laser_pixels=cal.laser_pixels,
             laser_plane=cal.laser_plane)
    real = load_calibration_data(q)
    assert np.isnan(real.angles).all() and np.isnan(real.laser_points_true).all()
    assert real.laser_points_true.shape == cal.laser_points_true.shape


def test_calibration_csv_pair(tmp_path, ds):
    cal = ds.calibration
    g = tmp_path / "grid.csv"
    g.write_text("plane,u,v,x,y,z\n" + "".join(
        f"{k},{a:.17g},{b:.17g},{x:.17g},{y:.17g},{z:.17g}\n" for k, (a, b), (x, y, z)
        in zip(cal.grid_plane, cal.grid_pixels, cal.grid_points, strict=True)))
    la = tmp_path / "laser.csv"
    la.write_text("plane,u,v\n" + "".join(f"{k},{a:.17g},{b:.17g}\n" for k, (a, b)
                                           in zip(cal.laser_plane, cal.laser_pixels,
                                                  strict=True)))
    back = load_calibration_data(g, la)
    np.testing.assert_array_equal(back.grid_points, cal.grid_points)
    np.testing.assert_array_equal(back.laser_plane, cal.laser_plane)
    with pytest.raises(InputError, match=r"needs the laser-on-planes CSV"):
        load_calibration_data(g)
    la.write_text("plane,u,v\n1.5,1,2\n")
    with pytest.raises(InputError, match=r"line 2, column 'plane': 1.5 is not a plane index"):
        load_calibration_data(g, la)


def test_calibration_npz_errors(tmp_path, ds):
    p = tmp_path / "c.npz"
    np.savez(p, grid_points=ds.calibration.grid_points)
    with pytest.raises(InputError, match=r"missing array\(s\) grid_pixels, grid_plane"):
        load_calibration_data(p)
    cal = ds.calibration
    np.savez(p, grid_points=cal.grid_points, grid_pixels=cal.grid_pixels[:-1],
             grid_plane=cal.grid_plane, laser_pixels=cal.laser_pixels,
             laser_plane=cal.laser_plane)
    with pytest.raises(InputError, match=r"grid_points has \d+ rows but grid_pixels has"):
        load_calibration_data(p)


def test_json_round_trip_keeps_non_finite_as_strings(tmp_path):
    p = write_json(tmp_path / "a.json", {"a": np.arange(3), "b": np.inf, "c": np.float64(0.5),
                                         "d": np.bool_(True)})
    assert read_json(p) == {"a": [0, 1, 2], "b": "inf", "c": 0.5, "d": True}
    (tmp_path / "bad.json").write_text("{\n  'x': 1}")
    with pytest.raises(InputError, match=r"bad.json, line 2: not valid JSON"):
        read_json(tmp_path / "bad.json")


@pytest.mark.parametrize("text, expected", [("800x600", (800, 600)), ("1280X960", (1280, 960))])
def test_parse_image_size(text, expected):
    assert parse_image_size(text) == expected


@pytest.mark.parametrize("text", ["800", "800x", "ax600", "0x600", "800x600x3"])
def test_parse_image_size_rejects(text):
    with pytest.raises(ValueError, match=r"image size must"):
        parse_image_size(text)


def test_read_table_optional_columns_only_when_asked(tmp_path):
    t = read_table(_write(tmp_path, "u,v,plane\n1,2,3\n"), required=("u",), optional=("v",))
    assert set(t.columns) == {"u", "v"}
    assert t.where(0, "u").endswith("line 2, column 'u'")


def test_offset_sd_line_is_read(tmp_path):
    # extract writes '# offset_sd: SD' (px); calibrate adds its variance to u0 and v0
    data = load_laser_data(_write(tmp_path, "# image_size: 800x600\n# offset_sd: 0.02\n" + GOOD))
    assert data.pixel_table.meta == {"image_size": (800, 600), "offset_sd": 0.02}
    assert "offset_sd" not in load_laser_data(_write(tmp_path, GOOD, "plain.csv")).pixel_table.meta
    for unit in ("0.02px", "0.02 px"):                       # the unit may follow the number
        meta = load_laser_data(_write(tmp_path, f"# offset_sd: {unit}\n" + GOOD, "u.csv"))
        assert meta.pixel_table.meta == {"offset_sd": 0.02}


@pytest.mark.parametrize("value", ["-0.1", "nan", "abc", "inf"])
def test_offset_sd_line_rejects(tmp_path, value):
    with pytest.raises(InputError, match=r"laser.csv, line 1: offset_sd"):
        load_laser_data(_write(tmp_path, f"# offset_sd: {value}\n" + GOOD))
