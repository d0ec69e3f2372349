"""Data collection through the plant FMU: the Python API, the CLI and the figures.

The reference is :meth:`Plant.record` on the same commands; the FMU wraps the same code, so
1e-12 (rad, m, N) only allows for reordered floating-point operations (observed: ~1e-16).
"""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.dataset import Dataset
from tendonkit.errors import FMUError, OptionError
from tendonkit.fmu.build import build_plant_fmu, cached_plant_fmu, plant_parameters
from tendonkit.fmu.plant import Plant, PlantConfig
from tendonkit.robot.collect import COLUMNS, PlantSession, collect
from tendonkit.robot.protocol import circles, pseudo_random

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_collect")

TOL = 1e-12
GROUPS = {
    "q": [f"q{i}" for i in range(1, 7)],
    "ee": ["ee_x", "ee_y", "ee_z"],
    "T_meas": ["T1", "T2", "T3", "T4"],
    "q_true": [f"q{i}_true" for i in range(1, 7)],
    "ee_true": ["ee_x_true", "ee_y_true", "ee_z_true"],
}


@pytest.fixture(scope="session")
def plant_fmu(tmp_path_factory):
    return build_plant_fmu(tmp_path_factory.mktemp("collect") / "plant.fmu")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("TENDONKIT_CACHE", str(folder))
    return folder


def assert_matches_record(rec, config: PlantConfig, u: np.ndarray) -> None:
    ref = Plant(config).record(u)
    np.testing.assert_array_equal(rec.columns["t"], ref["t"])
    np.testing.assert_array_equal(np.column_stack([rec.columns[f"u{k}"] for k in range(1, 5)]), u)
    for key, cols in GROUPS.items():
        got = np.column_stack([rec.columns[c] for c in cols])
        np.testing.assert_allclose(got, ref[key], rtol=0, atol=TOL, err_msg=key)


def test_collect_equals_plant_record(plant_fmu):
    prot = circles(radii=[0.03], laps=1)
    rec = collect(prot, plant=plant_fmu)
    assert tuple(rec.columns) == COLUMNS
    assert_matches_record(rec, PlantConfig(), prot.u)


def test_overrides_and_seed_reach_the_fmu_and_force_lag_aligns_like_record(plant_fmu):
    prot = pseudo_random(15.0, seed=1)
    effects = {"forcelag_on": "1", "noise_on": True, "delay_on": 1, "delay_s": "0.06"}
    rec = collect(prot, plant=plant_fmu, effects=effects, seed=5)
    assert rec.parameters["seed"] == 5 and rec.parameters["delay_s"] == 0.06
    config = PlantConfig(forcelag_on=True, noise_on=True, delay_on=True, delay_s=0.06, seed=5)
    assert_matches_record(rec, config, prot.u)
    ds = rec.to_dataset()
    assert isinstance(ds, Dataset) and ds.inputs == ("T1", "T2", "T3", "T4")
    assert ds.outputs == ("q1", "q2") and "q3_true" in ds.experiments[0].extra


def test_bad_overrides_are_reported_together(plant_fmu):
    prot = circles(radii=[0.02], laps=0.2)
    with pytest.raises(OptionError) as info:
        collect(prot, plant=plant_fmu, effects={"nosuch": 1, "friction_on": "maybe"})
    assert len(info.value.problems) == 2
    with pytest.raises(FMUError, match="delay_s must be in") as err:
        collect(prot, plant=plant_fmu, effects={"delay_s": 1.0, "friction_mu_s": 0.9})
    assert "friction_mu_s" in str(err.value)
    with pytest.raises(FMUError, match=r"steps at 0\.03"):
        collect(circles(radii=[0.02], laps=0.2, h=0.01), plant=plant_fmu)


def test_session_steps_one_frame_at_a_time(plant_fmu):
    u = np.tile([150.0, 105.0, 60.0, 105.0], (5, 1))
    ref = Plant().run(u)
    with PlantSession(plant_fmu) as session:
        first = session.outputs.copy()
        rows = [session.step(row).copy() for row in u]
    assert first[0] == 0.0 and first[9] == 105.0  # at rest, T1 = P_nom
    np.testing.assert_allclose(np.array(rows)[:, :6], ref["q"], rtol=0, atol=TOL)


def test_ratio_slopes_of_spec_14_from_a_collected_circle_csv(tmp_path, plant_fmu):
    # Spec §14: LS slopes over the 12 circles 0.650 ± 0.003, 0.206 ± 0.002, 0.646 ± 0.003,
    # 0.230 ± 0.002.  Two radii (6 and 12 cm, one lap) reproduce them within those bands
    # (the ratios of the nominal plant hardly depend on the amplitude).
    out = tmp_path / "circles.csv"
    args = ["collect", "--protocol", "circles", "--radii", "6,12", "--laps", "1"]
    assert main([*args, "--plant", str(plant_fmu), "-o", str(out), "--no-progress"]) == 0
    data = Dataset.from_csv(out, [], ["q1", "q2", "q3", "q4", "q5", "q6"], require_outputs=False)
    assert data.units["q3"] == "rad"  # header cells "q3 [rad]"

    def slope(a: str, b: str) -> float:
        x, y = data.signal(a), data.signal(b)
        return float(x @ y / (x @ x))

    assert slope("q1", "q3") == pytest.approx(0.650, abs=0.003)
    assert slope("q1", "q5") == pytest.approx(0.206, abs=0.002)
    assert slope("q2", "q4") == pytest.approx(0.646, abs=0.003)
    assert slope("q2", "q6") == pytest.approx(0.230, abs=0.002)


# --------------------------------------------------------------------------- CLI
def test_plant_build_cli_sets_start_values(tmp_path, capsys):
    from fmpy.validation import validate_fmu

    out = tmp_path / "fx.fmu"
    args = ["plant", "build", "-o", str(out), "--effect", "A", "D=0.12", "G"]
    assert main([*args, "--effect", "noise_on=1", "seed=3"]) == 0
    assert "friction" in capsys.readouterr().out
    assert validate_fmu(str(out)) == []
    with zipfile.ZipFile(out) as zf:
        params = json.loads(zf.read("resources/plant_parameters.json"))
    assert params["friction_on"] and params["delay_on"] and params["noise_on"]
    assert params["delay_s"] == 0.12 and params["mount"] == "horiz_tilt" and params["seed"] == 3
    assert params == plant_parameters(["A", "D=0.12", "G", "noise_on=1", "seed=3"])


def test_effect_switches_follow_the_spec_defaults():
    p = plant_parameters(["A=0.2", "K", "L=1.5", "F"], preset="paper_like")
    assert p["friction_mu_k"] == 0.2 and p["friction_mu_s"] == pytest.approx(0.2 * 0.16 / 0.12)
    assert p["hardening_on"] and p["hardening_k3"] == 2.0
    assert p["camera_fc"] == 1.5 and p["forcelag_on"] and p["mount"] == "horiz_tilt"


def test_collect_cli_writes_exact_columns_figures_and_summary(tmp_path, cache, capsys):
    out, figs, summary = tmp_path / "r.csv", tmp_path / "figs", tmp_path / "r.json"
    args = ["collect", "--protocol", "random", "--duration", "6", "--seed", "4", "-o", str(out)]
    assert main([*args, "--effect", "B", "--plot", str(figs), "--json", str(summary)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    expected = ["t [s]", *(f"{c} [N]" for c in ("u1", "u2", "u3", "u4", "T1", "T2", "T3", "T4"))]
    expected += [f"q{i} [rad]" for i in range(1, 7)] + ["ee_x [m]", "ee_y [m]", "ee_z [m]"]
    expected += [f"q{i}_true [rad]" for i in range(1, 7)]
    expected += ["ee_x_true [m]", "ee_y_true [m]", "ee_z_true [m]"]
    assert header == expected
    assert sorted(p.name for p in figs.iterdir()) == ["ee_path.png", "joint_angles.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in figs.iterdir())
    info = json.loads(summary.read_text())
    assert info["samples"] == 200 and info["parameters"]["backlash_on"] is True
    assert info["parameters"]["seed"] == 4
    # The default plant was built once into the cache and is reused.
    assert len(list((cache / "plant").glob("*.fmu"))) == 1
    assert "200 frames" in capsys.readouterr().out


def test_cached_plant_is_reused_and_keyed_by_parameters(cache):
    a = cached_plant_fmu()
    assert cached_plant_fmu() == a and a.stat().st_size > 0
    b = cached_plant_fmu(plant_parameters(["A"]))
    assert b != a


def test_bad_effects_exit_2_listing_every_problem_without_traceback(tmp_path, cache):
    out = tmp_path / "x.csv"
    r = subprocess.run(
        [
            *(sys.executable, "-m", "tendonkit.cli", "collect", "--protocol", "circles"),
            *("--effect", "Q", "delay_s=abc", "friction_mu_k=0.9", "--radii", "2,x"),
            *("-o", str(out)),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    for text in (
        "unknown effects or parameters: 'Q'",
        "switches: A, B, D",
        "delay_s has an invalid value 'abc'",
        "friction_mu_k must be in [0.05, 0.3]",
        "--radii: 'x' is not a number",
    ):
        assert text in r.stderr
    assert not out.exists()


def test_plant_build_rejects_bad_preset_and_output(tmp_path, capsys):
    assert main(["plant", "build", "-o", str(tmp_path / "nope" / "p.fmu"), "--preset", "x"]) == 2
    err = capsys.readouterr().err
    assert "unknown preset 'x'" in err and "does not exist" in err
