"""What frame calibration refuses (daddpg_jax/deploy/calibrate.py, daddpg-calibrate) and the
client-side check of a limits file's calibration (`RobotLimits.check_calibration`). NumPy only,
in-process. Cost: ~0.01-0.05 s per test, ~1.5 s the module (32 tests)."""

from __future__ import annotations

import json
import os
import shutil
import tomllib

import numpy as np
import pytest

from daddpg_jax.cli import calibrate as calibrate_cli
from daddpg_jax.deploy import calibrate
from daddpg_jax.deploy.arms import base_transform, invert
from daddpg_jax.deploy.limits import SHIPPED, LimitsError, RobotLimits
from daddpg_jax.deploy.ur3 import BASE_POS, BASE_YAW

BOARD = os.path.join(SHIPPED, "board_example.json")
SIM_LIMITS = os.path.join(SHIPPED, "sim.toml")
ARMS = (("left", "l"), ("right", "r"))
# each base's true error: offset m, yaw deg (within the default 5 cm / 10 deg)
OFFSET = ([0.02, 0.01, 0.0], [-0.01, -0.02, 0.005])
YAW = (2.0, -2.0)


def _board() -> dict:
    with open(BOARD) as f:
        return {a: np.asarray(v, float) for a, v in json.load(f).items()}


def _measure(points, noise_mm=0.5, seed=0) -> dict:
    """Readings of ``points`` in the true base frames, Gaussian noise of noise_mm RMS/point."""
    rng = np.random.default_rng(seed)
    out = {}
    for i, (arm, a) in enumerate(ARMS):
        inv = invert(base_transform(BASE_POS[a] + OFFSET[i], BASE_YAW[a] + np.radians(YAW[i])))
        w = np.asarray(points[arm], float)
        out[arm] = (w @ inv[:3, :3].T + inv[:3, 3]
                    + rng.normal(0.0, noise_mm * 1e-3 / np.sqrt(3.0), w.shape))
    return out


def _calibrate(points, measured, model="yaw", **kw):
    fits = calibrate.fit_arms(points, measured, model)
    calibrate.check_fits(points, measured, fits, model, **kw)
    return fits


@pytest.mark.parametrize("model", calibrate.MODELS)
def test_the_example_board_with_noise_is_accepted_and_recovers_the_bases(model):
    """~0.01 s each: the shipped board (8 coplanar points per arm), 0.5 mm RMS noise, bases 2 cm
    and 2 deg off nominal: accepted, each base within 1 mm and 0.1 deg of the truth."""
    fits = _calibrate(_board(), _measure(_board()), model)
    for i, (arm, a) in enumerate(ARMS):
        true = base_transform(BASE_POS[a] + OFFSET[i], BASE_YAW[a] + np.radians(YAW[i]))
        pos, ang = calibrate.pose_error(fits[arm][0], true)
        assert pos < 1e-3 and ang < 0.1 and np.max(fits[arm][1]) < 2e-3


def _swapped(p, m):
    return p, {"left": m["right"], "right": m["left"]}


def _labels_swapped(p, m):
    return {"left": p["right"], "right": p["left"]}, {"left": m["right"], "right": m["left"]}


def _one_point_off(p, m):
    m = {a: v.copy() for a, v in m.items()}
    m["left"][2] += [0.1, 0.0, 0.0]
    return p, m


def _scaled(p, m):
    return p, {a: 1.5 * v for a, v in m.items()}


def _far(p, m):
    return {a: v + [1.5, 0.0, 0.0] for a, v in p.items()}, m


def _mirrored(p, m):
    m = {a: v.copy() for a, v in m.items()}
    m["right"][:, 0] *= -1.0
    return p, m


def _noisy(p, m):
    return p, _measure(p, noise_mm=5.0)


def _turned(p, m):
    m = dict(m)
    m["left"] = m["left"] @ base_transform([0, 0, 0], np.radians(20.0))[:3, :3].T
    return p, m


@pytest.mark.parametrize("model", calibrate.MODELS)
@pytest.mark.parametrize("spoil, msg", [
    (_swapped, r"left and right readings are swapped: each fits the other arm's points"),
    (_labels_swapped, r"left base fits 0\.0\d\d m from the right arm's nominal base .* swapped"),
    (_one_point_off, r"left point 3 \[0\.1400, 0\.1870, 0\.4100\] m is an outlier: 10\d\.\d mm "
                     r".*no point is dropped"),
    (_scaled, r"left readings fit its points only with a scale of 0\.666.*1\.500 x the board"),
    (_far, r"left base fits 1\.5\d\d m .* from its nominal pose.*--allow-far-base"),
    (_mirrored, r"right readings are a mirror image of its points"),
    (_noisy, r"left fit has rms [3-9]\.\d\d mm.*calibration_max_rms_mm 3"),
    (_turned, r"left base fits 0\.022 m and 18\.0 deg from its nominal pose"),
])
def test_each_kind_of_nonsense_is_refused_in_one_line(spoil, msg, model):
    """~0.01 s each: the failures seen before (readings swapped between the arms, one point
    10 cm off, readings 1.5 x too large, a board 1.5 m away) and the other refusals (arm labels
    swapped, a mirrored reading, 5 mm noise, a base turned 20 deg): CalibrationError, one line,
    naming the cause."""
    p, m = spoil(_board(), _measure(_board()))
    with pytest.raises(calibrate.CalibrationError, match=msg) as e:
        _calibrate(p, m, model)
    assert "\n" not in str(e.value)


def test_a_far_base_is_accepted_only_when_allowed():
    """~0.01 s: the board 1.5 m away passes with allow_far_base, which waives nothing else."""
    p, m = _far(_board(), _measure(_board()))
    fits = _calibrate(p, m, allow_far_base=True)
    assert abs(fits["left"][0][0, 3] - 1.52) < 2e-3  # 1.5 m + the 2 cm error
    p, m = _scaled(p, m)
    with pytest.raises(calibrate.CalibrationError, match="scale"):
        _calibrate(p, m, allow_far_base=True)


def _grid(nx, ny, step):
    return np.array([[0.2 + i * step, 0.1 + j * step, 0.41]
                     for i in range(nx) for j in range(ny)])


@pytest.mark.parametrize("left, msg", [
    (_board()["left"][:5], "left arm: at least 6 points are needed, got 5"),
    (np.c_[np.linspace(0.15, 0.35, 8), np.full(8, 0.1), np.full(8, 0.41)],
     "left arm: the points lie on one line"),
    (_grid(3, 2, 0.04), r"left arm: the points span 8\.0 x 4\.0 cm: at least 10 cm in two "
                        r"directions"),
])
def test_too_few_collinear_or_too_small_point_sets_are_refused(left, msg):
    """~0.01 s each: 5 points, 8 points on one line, 6 points spanning 8 x 4 cm."""
    p = _board()
    p["left"] = left
    with pytest.raises(calibrate.CalibrationError, match=msg):
        calibrate.fit_arms(p, _measure(p))


def test_six_points_spanning_10_cm_are_enough():
    """~0.01 s: the smallest accepted set, a 3 x 2 grid of 5 cm x 10 cm steps (10 x 10 cm)."""
    p = {"left": _grid(3, 2, 0.05) * [1, 2, 1] - [0, 0.1, 0],
         "right": (_grid(3, 2, 0.05) * [1, 2, 1] - [0, 0.1, 0]) * [1, -1, 1]}
    _calibrate(p, _measure(p))


def test_thresholds_come_from_the_limits_file(tmp_path):
    """~0.02 s: 5 mm of noise is refused with the defaults and accepted with looser
    calibration_max_rms_mm / calibration_max_residual_mm read from a limits file."""
    p, m = _noisy(_board(), None)
    with pytest.raises(calibrate.CalibrationError, match="rms"):
        _calibrate(p, m, limits=RobotLimits())
    path = tmp_path / "loose.toml"
    path.write_text(open(SIM_LIMITS).read().replace(
        "[left]", "calibration_max_rms_mm = 8.0\ncalibration_max_residual_mm = 15.0\n\n[left]", 1))
    _calibrate(p, m, limits=RobotLimits.load(path))


def _cli(tmp_path, points, measured, *extra):
    lim = tmp_path / "cell.toml"
    if not lim.exists():
        shutil.copy(SIM_LIMITS, lim)
    for name, d in (("points.json", points), ("measured.json", measured)):
        (tmp_path / name).write_text(json.dumps({a: np.asarray(v).tolist() for a, v in d.items()}))
    return lim, calibrate_cli.main(["--limits", str(lim), "--points", str(tmp_path / "points.json"),
                                    "--measured", str(tmp_path / "measured.json"), *extra])


def test_cli_reports_each_point_and_writes_a_calibration_the_client_accepts(tmp_path, capsys):
    """~0.05 s: the example board with 0.5 mm noise: exit 0, a residual line per point (16),
    the block written, and `check_calibration` of the file passes."""
    lim, rc = _cli(tmp_path, _board(), _measure(_board()))
    out = capsys.readouterr().out
    assert rc == 0
    lines = [ln for ln in out.splitlines() if " point " in ln and "residual" in ln]
    assert len(lines) == 16 and lines[2].startswith("left point 3 [0.1400, 0.1870, 0.4100] m:")
    limits = RobotLimits.load(lim)
    assert len(limits.calibration["left"]["residuals_mm"]) == 8
    limits.check_calibration()


def test_cli_refusal_exits_2_in_one_line_and_writes_nothing(tmp_path, capsys):
    """~0.05 s: one point 10 cm off: the residuals are still printed, stderr is one line naming
    the point, exit 2, the limits file unchanged; the far board needs --allow-far-base."""
    lim, rc = _cli(tmp_path, *_one_point_off(_board(), _measure(_board())))
    out, err = capsys.readouterr()
    assert rc == 2 and "left point 3 " in out
    assert err.count("\n") == 1 and err.startswith("error: refused: left point 3 ")
    assert "calibration" not in lim.read_text()
    p, m = _far(_board(), _measure(_board()))
    assert _cli(tmp_path, p, m)[1] == 2
    assert _cli(tmp_path, p, m, "--allow-far-base")[1] == 0
    assert "[calibration.left]" in lim.read_text()


# -- the client's check of a limits file's calibration -------------------------------------------

def _entry(residuals_mm, **extra):
    return {"base_pos": [0.0, 0.25, 0.4], "base_rotvec": [0.0, 0.0, 3.1],
            "residuals_mm": residuals_mm, **extra}


@pytest.mark.parametrize("left, msg", [
    ({"base_pos": [0.0, 0.25, 0.4], "base_rotvec": [0.0, 0.0, 3.1]},
     "left arm .* carries 0 residuals"),
    (_entry([0.5] * 4), "carries 4 residuals"),
    (_entry([3.5] * 8), "RMS residual of 3.5 mm, over calibration_max_rms_mm 3"),
    (_entry([0.5] * 7 + [6.5]), "residual of 6.5 mm at point 8, over calibration_max_residual"),
    (_entry([0.5] * 8, rms_mm=4.0), "RMS residual of 4 mm"),
])
def test_check_calibration_refuses_missing_or_large_residuals(left, msg):
    """~0.01 s each: no residuals, too few, RMS over, one over, a written rms_mm over."""
    limits = RobotLimits(calibration={"left": left, "right": _entry([0.5] * 8)})
    with pytest.raises(LimitsError, match=msg):
        limits.check_calibration()


def test_check_calibration_passes_nominal_and_good_calibrations_and_follows_the_file():
    """~0.01 s: no calibration and a good one pass; the thresholds are the limits' own and are
    validated; the shipped ur3_cell.toml loads unchanged and with its optional lines set."""
    RobotLimits().check_calibration()
    good = {"left": _entry([0.5] * 8), "right": _entry([1.0] * 6)}
    RobotLimits(calibration=good).check_calibration()
    with pytest.raises(LimitsError, match="calibration_max_rms_mm"):
        RobotLimits(calibration=good, calibration_max_rms_mm=0.8).check_calibration()
    for bad in (0.0, -1.0, float("nan"), "3"):
        with pytest.raises(LimitsError, match="calibration_max_residual_mm"):
            RobotLimits(calibration_max_residual_mm=bad)
    with open(os.path.join(SHIPPED, "ur3_cell.toml")) as f:
        text = f.read()
    base = RobotLimits.from_dict(tomllib.loads(text))
    assert (base.calibration_max_rms_mm, base.calibration_max_residual_mm,
            base.calibration_max_base_offset_m, base.calibration_max_base_angle_deg) == (
        3.0, 6.0, 0.05, 10.0)
    opened = text.replace("# calibration_max_", "calibration_max_")
    assert opened.count("\ncalibration_max_") == 4
    assert RobotLimits.from_dict(tomllib.loads(opened)) == base
