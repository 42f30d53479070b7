import json

import numpy as np
import pytest
import yaml

from plsgraph.core.geometry import make_T, so3_exp
from plsgraph.errors import InputError
from plsgraph.report.files import (
    calibration_dict,
    html_report,
    html_table,
    prepare_output_dir,
    ros_static_transform,
    write_json,
    write_yaml,
)


def _T():
    return make_T(so3_exp([0.1, -0.2, 0.3]), [0.15, 0.02, 0.25])


def test_calibration_dict_round_trips_through_yaml_and_json(tmp_path):
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1.0, 1e-6])
    obs = [{"direction": "translation z (camera height)", "status": "unobservable", "sigma": 1.0, "note": "prior"}]
    d = calibration_dict(_T(), 0.031, cov, obs)
    write_yaml(tmp_path / "c.yaml", d)
    write_json(tmp_path / "c.json", d)
    y = yaml.safe_load((tmp_path / "c.yaml").read_text())
    j = json.loads((tmp_path / "c.json").read_text())
    for loaded in (y, j):
        T = np.array(loaded["T_base_cam"])
        assert np.allclose(T, _T())
        q = np.array(loaded["quaternion_xyzw"])
        assert np.isclose(np.linalg.norm(q), 1.0)
        assert loaded["time_offset_s"] == pytest.approx(0.031)
        assert np.allclose(loaded["covariance"]["matrix"], cov)
        assert loaded["covariance"]["order"][-1] == "td"
        assert loaded["observability"][0]["status"] == "unobservable"


def test_nan_becomes_null_not_invalid_json(tmp_path):
    write_json(tmp_path / "r.json", {"a": float("nan"), "b": np.array([1.0, np.inf])})
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": None, "b": [1.0, None]}


def test_static_transform_line_encodes_the_pose():
    line = ros_static_transform(_T())
    tok = line.split()
    vals = dict(zip(tok[4::2], tok[5::2], strict=True))
    assert float(vals["--x"]) == pytest.approx(0.15) and float(vals["--z"]) == pytest.approx(0.25)
    q = np.array([float(vals[k]) for k in ("--qx", "--qy", "--qz", "--qw")])
    assert np.isclose(np.linalg.norm(q), 1.0, atol=1e-8)


def test_output_dir_refuses_to_overwrite(tmp_path):
    out = prepare_output_dir(tmp_path / "o")
    (out / "calibration.yaml").write_text("old")
    with pytest.raises(InputError, match="--force"):
        prepare_output_dir(out)
    assert prepare_output_dir(out, force=True) == out
    assert (out / "calibration.yaml").read_text() == "old"


def test_html_escapes_text():
    page = html_report("<t>", [("s", html_table([{"status": "weak", "x": "<b>"}], ["status", "x"]))], [])
    assert "&lt;b&gt;" in page and "<b>" not in page.split("<h2>s</h2>")[1]


def test_log_axes_of_the_figures_are_labelled_in_plain_numbers(tmp_path):
    from PIL import Image

    from plsgraph.report.figures import DPI, _plain_ticks, _plt, _save

    plt = _plt()
    fig, ax = plt.subplots(figsize=(3.0, 2.0), dpi=DPI)
    ax.bar([0, 1, 2], [0.002, 0.3, 40.0])
    ax.set_yscale("log")
    _plain_ticks(ax.yaxis)
    fig.canvas.draw()
    labels = [t.get_text() for t in ax.yaxis.get_ticklabels() if t.get_text()]
    assert labels and not any("$" in s for s in labels)  # no typeset maths: the dearest text to draw
    assert {"0.01", "1", "10"} <= set(labels)
    assert not any(t.get_text() for t in ax.yaxis.get_ticklabels(minor=True))
    name = _save(plt, fig, tmp_path, "log.png")
    with Image.open(tmp_path / name) as im:  # made at the resolution it is saved at: the size the layout measured
        assert im.size == (round(3.0 * DPI), round(2.0 * DPI))
