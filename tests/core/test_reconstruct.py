"""Kinematic reconstruction: ratios, six joints, end-effector error, compare --joints/--ee."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tendonkit.compare import compare
from tendonkit.dataset import Dataset, Experiment
from tendonkit.errors import DataError
from tendonkit.fmu import plant as fmu_plant
from tendonkit.robot.kinematics import forward_kinematics
from tendonkit.robot.protocol import circles, pseudo_random
from tendonkit.robot.reconstruct import (
    Ratios,
    ee_error_cm,
    estimate_ratios,
    joint_extras,
    reconstruct,
)


def _exp(proto, name, noise=False, seed=0):
    from tendonkit.fmu._config import PlantConfig

    plant = fmu_plant.Plant(PlantConfig(noise_on=noise, seed=seed))
    plant.reset()
    log = plant.record(proto.u)
    extra = {f"q{i + 1}": log["q"][:, i] for i in range(6)}
    extra.update({"ee_x": log["ee"][:, 0], "ee_y": log["ee"][:, 1], "ee_z": log["ee"][:, 2]})
    return Experiment(t=log["t"], u=log["T_meas"], y=log["q"][:, :2], name=name, extra=extra)


@pytest.fixture(scope="module")
def plant_data():
    tr = Dataset(
        ("T1", "T2", "T3", "T4"),
        ("q1", "q2"),
        (
            _exp(circles(radii=[0.03, 0.08, 0.12], laps=1), "c", True, 1),
            _exp(pseudo_random(60, seed=1), "r", True, 2),
        ),
        0.03,
    )
    va = Dataset(
        ("T1", "T2", "T3", "T4"),
        ("q1", "q2"),
        (
            _exp(pseudo_random(40, seed=7), "r", True, 3),
            _exp(circles(radii=[0.065], laps=1, clockwise=True), "c", True, 4),
        ),
        0.03,
    )
    return tr, va


def test_least_squares_ratios_match_the_plant_within_0_01(plant_data):
    """The plant's ratios come out of its physics (spec §8: 0.6496, 0.2055, 0.6455, 0.2299)."""
    tr, _ = plant_data
    q = np.column_stack([tr.signal(f"q{i}") for i in range(1, 7)])
    est = estimate_ratios(q)
    truth = {"q3": 0.6496, "q5": 0.2055, "q4": 0.6455, "q6": 0.2299}
    for key, value in truth.items():
        assert est["least_squares"].to_dict()[key] == pytest.approx(value, abs=0.01)
    assert set(est) == {"least_squares", "extremes"}


def test_estimates_recover_exact_ratios_of_constructed_data():
    rng = np.random.default_rng(0)
    q12 = rng.uniform(-0.3, 0.3, size=(500, 2))
    r = Ratios(0.6, 0.5, 0.25, 0.2)
    est = estimate_ratios(reconstruct(q12, r))
    for method in ("least_squares", "extremes"):
        for key, value in r.to_dict().items():
            assert est[method].to_dict()[key] == pytest.approx(value, rel=1e-12)


def test_end_effector_error_of_a_known_shift():
    q = np.zeros((10, 6))
    ee = forward_kinematics(q)
    assert ee_error_cm(ee, ee + np.array([0.03, 0.04, 0.0])) == pytest.approx(5.0)


def test_ratios_file_problems_are_listed(tmp_path):
    bad = tmp_path / "r.json"
    bad.write_text(json.dumps({"q3": "x", "q4": 0.6, "zz": 1}))
    with pytest.raises(DataError) as info:
        Ratios.load(bad)
    text = str(info.value)
    assert "q3: expected a finite number" in text and "q5" in text and "unknown keys ['zz']" in text


def test_compare_reports_joint_fits_and_ee_error(plant_data, tmp_path):
    import tendonkit as tk

    tr, va = plant_data
    model = tk.identify(tr, "arx")
    res = compare(
        [model],
        va,
        names=["arx"],
        plot_dir=tmp_path,
        extras=joint_extras(joints=True, ee=True, plot_dir=tmp_path),
    )
    row = res["models"][0]
    assert set(row["joint_fit"]) == {f"q{i}" for i in range(1, 7)}
    assert row["joint_fit"]["q1"] == pytest.approx(row["fit"]["q1"])  # modelled joints agree
    assert min(row["joint_fit"].values()) > 60  # the reconstruction follows the real joints
    assert 0 < row["ee_error_cm"] < 3
    assert len(list(tmp_path.glob("*.png"))) >= 3


def test_joint_report_needs_q1_q2_outputs(plant_data):
    import tendonkit as tk

    tr, va = plant_data
    model = tk.identify(tr.select(["T1", "T2", "T3", "T4"], ["q3", "q4"]), "arx", na=2, nb=2)
    with pytest.raises(DataError, match="outputs named q1 and q2"):
        compare(
            [model],
            va.select(["T1", "T2", "T3", "T4"], ["q3", "q4"]),
            extras=joint_extras(joints=False, ee=True),
        )
