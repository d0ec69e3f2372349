"""``tendonkit demo``: the paper's whole study on the embedded plant, with an HTML report.

1. Build the plant FMU with the paper-like preset (friction, force lag, 30 ms delay, horizontal
   mounting, 2 Hz camera; plus sensor noise) and collect identification and validation data
   with the paper's protocol (circles 1–12 cm, pseudo-random motion; validation: another seed,
   other radii, clockwise).
2. Identify N4SID (order 8), ARX (8, 8, 1) and SINDYc (threshold by sweep); print Table I beside
   the paper's numbers.
3. Reconstruct all six joints and the end effector; estimate the ratios from the data.
4. Diagnose both halves of the actuation chain: the linear MPC's model (N4SID) from the
   commanded forces, where the force controllers' lag acts, and the best model from the
   measured tendon tensions ``T1..T4``, where the tendons' friction acts; each names its causes
   with their gains.
5. Export the linear MPC's model (extended when a cause was named) as an FMU and check it in
   fmpy.
6. Linear MPC (N4SID, and N4SID extended by the diagnosis when it is linear) and nonlinear MPC
   (SINDYc) on the petal in co-simulation: the payoff of the better model in tracking error.

The inputs of the identified models are the *commanded* tendon forces ``u1..u4``: they are what
the MPC sends to the robot's force controllers, so these are the models a controller can use
(the measured forces lag the commands on this plant).  The tensions' diagnosis is the other
half of the chain: what happens between the measured forces and the joints.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..compare import compare, score
from ..diagnose import diagnose
from ..diagnose.report import write_report
from ..errors import TendonkitError
from ..files import write_json
from ..manager import identifiers
from ..report import Report
from ..schema import LINEAR_BLOCKS
from ..stepper import Stepper
from . import protocol
from .campaign import run_campaign, spec_from_dict
from .collect import collect
from .cosim import make_controller, make_reference, open_loop, plot_tracking, run
from .figures import fig2
from .reconstruct import Ratios, estimate_ratios, joint_report

#: The paper's Table I (validation fit, mean over q1 and q2, percent).
PAPER_FIT = {"sindyc": 67.74, "arx": 44.90, "n4sid": 39.12}
PAPER_EE_ERROR_CM = 2.48
INPUTS = ("u1", "u2", "u3", "u4")
OUTPUTS = ("q1", "q2")
#: The measured tendon tensions: the inputs of the mechanism's half of the actuation chain.
TENSIONS = ("T1", "T2", "T3", "T4")


class _Stages:
    """Prints each stage with its duration (the progress of the demo)."""

    def __init__(self, total: int, enabled: bool = True) -> None:
        self.total, self.n, self.enabled = total, 0, enabled
        self.t0 = time.perf_counter()
        self.times: dict[str, float] = {}

    def run(self, title: str, fn: Callable[[], Any]) -> Any:
        self.n += 1
        if self.enabled:
            print(f"[{self.n}/{self.total}] {title} ...", flush=True)
        t = time.perf_counter()
        out = fn()
        self.times[title] = time.perf_counter() - t
        if self.enabled:
            print(f"      done in {self.times[title]:.1f} s", flush=True)
        return out


def _protocols(quick: bool, seed: int) -> dict[str, Any]:
    radii = [0.02, 0.05, 0.08, 0.12] if quick else None
    return {
        "train_circles": protocol.circles(radii=radii, laps=1 if quick else 2),
        "train_random": protocol.pseudo_random(duration=60 if quick else 240, seed=seed),
        "valid_random": protocol.pseudo_random(duration=40 if quick else 120, seed=seed + 1000),
        "valid_circles": protocol.circles(radii=[0.015, 0.065, 0.115], laps=1, clockwise=True),
    }


def _collect(out: Path, quick: bool, seed: int, progress: bool) -> dict[str, Any]:
    # lazy: keeps this module off tendonkit.fmu until needed
    from tendonkit.fmu.build import build_plant_fmu
    from tendonkit.fmu.plant import PlantConfig

    config = PlantConfig.preset("paper_like").replace(noise_on=True, seed=seed)
    plant = build_plant_fmu(out / "plant_paper_like.fmu", config)
    recs = {}
    (out / "data").mkdir(parents=True, exist_ok=True)
    for i, (name, prot) in enumerate(_protocols(quick, seed).items()):
        rec = collect(prot, plant=plant, seed=seed + i, progress=progress)
        rec.to_csv(out / "data" / f"{name}.csv")
        recs[name] = rec

    def joined(inputs: tuple[str, ...], first: str, second: str) -> Any:
        return (
            recs[first].to_dataset(inputs, OUTPUTS).concat(recs[second].to_dataset(inputs, OUTPUTS))
        )

    return {
        "plant": plant,
        "config": config,
        "recordings": recs,
        "train": joined(INPUTS, "train_circles", "train_random"),
        "valid": joined(INPUTS, "valid_random", "valid_circles"),
        "train_tensions": joined(TENSIONS, "train_circles", "train_random"),
        "valid_tensions": joined(TENSIONS, "valid_random", "valid_circles"),
    }


def _identify(train: Any, quick: bool) -> dict[str, Any]:
    reg = identifiers()
    plan = {"n4sid": {"order": 8}, "arx": {"na": 8, "nb": 8, "nk": 1}, "sindyc": {}}
    return {m: reg.get(m).create(**opts).identify(train) for m, opts in plan.items()}


def _table(models: dict[str, Any], valid: Any) -> dict[str, Any]:
    res = compare(list(models.values()), valid, names=list(models))
    for row in res["models"]:
        row["paper_mean_fit"] = PAPER_FIT.get(row["model"])
    return res


def _render_table(res: dict[str, Any]) -> str:
    lines = [
        "Table I — validation fit [%] (free run, initial state estimated), ours vs the paper's",
        f"{'method':<8} {'fit q1':>8} {'fit q2':>8} {'mean':>8} {'paper':>8}",
    ]
    for r in res["models"]:
        f = r["fit"]
        lines.append(
            f"{r['model']:<8} {f['q1']:>8.2f} {f['q2']:>8.2f} {r['mean_fit']:>8.2f} "
            f"{r['paper_mean_fit']:>8.2f}"
        )
    lines.append(
        "Ours differ from the paper's because our plant is not their robot: its geometry and "
        "effects are a reconstruction (plant.md), the data come from a simulator with known "
        "noise and no unmodelled wear, and the paper's offline low-pass filter is not applied."
    )
    return "\n".join(lines)


def _reconstruction(models: dict[str, Any], data: dict[str, Any], out: Path) -> dict[str, Any]:
    train, valid = data["train"], data["valid"]
    q_train = np.column_stack([train.signal(f"q{i}") for i in range(1, 7)])
    est = estimate_ratios(q_train)
    rows = {}
    for name, model in models.items():
        _, sims = score(model, valid)
        rows[name] = joint_report(
            model, valid, sims, ratios=Ratios(), plot_dir=out / "figures", name=name
        )
    return {
        "estimated_ratios": {k: r.to_dict() for k, r in est.items()},
        "paper_ratios": Ratios().to_dict(),
        "models": rows,
    }


def _render_reconstruction(rec: dict[str, Any]) -> str:
    lines = ["Joint ratios (q3/q1, q4/q2, q5/q1, q6/q2):"]
    for label, r in (("paper", rec["paper_ratios"]), *rec["estimated_ratios"].items()):
        lines.append(f"  {label:<14} " + "  ".join(f"{k} {v:.4f}" for k, v in r.items()))
    lines.append("Reconstructed joints (paper ratios) — validation fit [%] and end-effector error:")
    for name, row in rec["models"].items():
        fits = "  ".join(f"{j} {v:5.1f}" for j, v in row["joint_fit"].items())
        lines.append(
            f"  {name:<7} {fits}   EE {row['ee_error_cm']:.2f} cm (paper {PAPER_EE_ERROR_CM} cm)"
        )
    return "\n".join(lines)


def _diagnose(
    models: dict[str, Any],
    data: dict[str, Any],
    out: Path,
    quick: bool,
    progress: bool = False,
) -> dict[str, dict[str, Any]]:
    """Both halves of the actuation chain, each diagnosed with its causes and gains.

    ``commanded``: the linear MPC's model (N4SID, commanded forces → joints), so that what it
    names extends the model the MPC then uses (the force controllers' lag acts here).
    ``tensions``: the best of the three identifiers on the measured tensions → joints (Table I's
    rule on that data), where the tendons' friction acts without the lag in front of it.
    """
    commanded = _diagnose_one(
        models["n4sid"],
        "n4sid",
        data["train"],
        data["valid"],
        out / "diagnose",
        "the linear MPC's model, commanded forces u1..u4 → joints",
        progress,
    )
    on_tensions = _identify(data["train_tensions"], quick)
    table = _table(on_tensions, data["valid_tensions"])
    best = max(table["models"], key=lambda r: r["mean_fit"])["model"]
    tensions = _diagnose_one(
        on_tensions[best],
        best,
        data["train_tensions"],
        data["valid_tensions"],
        out / "diagnose_tensions",
        "the best model on the measured tensions T1..T4 → joints",
        progress,
    )
    return {"commanded": commanded, "tensions": tensions}


def _diagnose_one(
    model: Any,
    method: str,
    train: Any,
    valid: Any,
    folder: Path,
    what: str,
    progress: bool,
) -> dict[str, Any]:
    options = dict(model.provenance.options)
    if method == "sindyc" and "threshold" in model.provenance.details:
        options["threshold"] = model.provenance.details["threshold"]  # no sweep per candidate
    result = diagnose(train, valid, method=method, options=options, progress=progress)
    path = folder / "extended_model.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    result.extended.save(path)
    write_report(result, valid, folder, str(path))
    return {
        "method": method,
        "what": what,
        "folder": folder.name,
        "result": result,
        "summary": result.to_dict(str(path)),
        "model_path": path,
    }


def _render_diagnosis(d: dict[str, Any]) -> str:
    s = d["summary"]
    causes = s.get("causes") or [s["cause"]]
    lines = [f"Diagnosis of {d['what']} ({d['method']}): causes = {', '.join(causes)}"]
    if s["cause"] != "none":
        e = s["extended"]
        for st in s.get("sequence") or []:
            if st["cause"] == "none":
                continue
            lines.append(
                f"  step {st['step']}: {st['cause']} {json.dumps(st['params'], default=str)[:120]}"
                f" — fit {st['fit_before']:.2f} -> {st['fit']:.2f} % (gain {st['gain']:+.2f})"
            )
        lines.append(
            f"  validation fit {s['baseline']['fit']:.2f} % -> {e['fit']:.2f} % "
            f"(total gain {e.get('total_gain', e['gain']):+.2f} points)"
        )
    for f in s["findings"][:4]:
        lines.append(
            f"  {'*' if f['significant'] else ' '} {f['cause']:<20} gain {f['gain']:+7.2f}"
            f"  p_adj={f.get('p_adjusted', f['p_value']):.2g}"
        )
    return "\n".join(lines)


def _export(diag: dict[str, Any], valid: Any, out: Path) -> dict[str, Any]:
    # lazy: heavy (fmpy); keeps this module off tendonkit.fmu until needed
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    from tendonkit.fmu.build import build_model_fmu  # lazy: keeps this module off fmu

    model = diag["result"].extended
    path = build_model_fmu(model, out / "model.fmu")
    problems = validate_fmu(str(path))
    e = valid.experiments[0]
    n = min(400, e.n_samples)
    u = e.u[:n]
    dt = model.dt
    signals = np.zeros(
        n, dtype=[("time", np.float64)] + [(name, np.float64) for name in model.input_names]
    )
    signals["time"] = dt * np.arange(n)
    for j, name in enumerate(model.input_names):
        signals[name] = u[:, j]
    res = simulate_fmu(
        str(path),
        start_time=0.0,
        stop_time=dt * (n - 1),
        step_size=dt,
        input=signals,
        output=list(model.output_names),
        output_interval=dt,
    )
    stepper = Stepper(model)
    ref = np.array([stepper.step(u[k]) for k in range(n)])
    got = np.column_stack([res[name] for name in model.output_names])[: len(ref)]
    # fmpy reads outputs after each step: compare the states both advance through
    m = min(len(got), len(ref))
    lag = 0 if np.allclose(got[:m], ref[:m], atol=1e-9) else 1
    diff = float(np.max(np.abs(got[lag:m] - ref[: m - lag]))) if m > lag else float("nan")
    return {"path": path, "problems": list(problems), "max_difference": diff, "n_steps": n}


def run_demo(
    out: str | Path = "demo-report", *, quick: bool = False, seed: int = 0, progress: bool = True
) -> dict[str, Any]:
    """Run the whole study; write ``index.html`` and ``summary.json`` into ``out``.

    Parameters
    ----------
    out : path
        Output folder (created).
    quick : bool
        Smaller data and shorter co-simulations (about a minute).
    seed : int
        Seed of every random choice (protocols, noise).
    progress : bool
        Print the stages as they run.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stages = _Stages(8, progress)
    t0 = time.perf_counter()
    data = stages.run(
        "build the paper-like plant FMU and collect data (paper protocol)",
        lambda: _collect(out, quick, seed, progress),
    )
    figs2 = _fig2(data, out)
    models = stages.run(
        "identify N4SID (order 8), ARX (8, 8, 1) and SINDYc",
        lambda: _identify(data["train"], quick),
    )
    for name, model in models.items():
        model.save(out / f"{name}.json")
    table = _table(models, data["valid"])
    print(_render_table(table))
    rec = stages.run(
        "reconstruct six joints and the end effector", lambda: _reconstruction(models, data, out)
    )
    print(_render_reconstruction(rec))
    diag = stages.run(
        "diagnose both halves of the actuation chain (commanded forces; measured tensions)",
        lambda: _diagnose(models, data, out, quick, progress),
    )
    print(_render_diagnosis(diag["commanded"]))
    print(_render_diagnosis(diag["tensions"]))
    extended = diag["commanded"]["result"].cause != "none"
    exp = stages.run(
        "export the extended N4SID model as an FMU and check it in fmpy"
        if extended
        else "export the N4SID model (no cause named, nothing extended) as an FMU and check it",
        lambda: _export(diag["commanded"], data["valid"], out),
    )
    print(
        f"Model FMU {exp['path'].name}: fmpy validation problems: {len(exp['problems'])}; "
        f"max |FMU - tendonkit| over {exp['n_steps']} steps: {exp['max_difference']:.2e}"
    )
    mpc = stages.run(
        "MPC on the petal in co-simulation (linear on N4SID and on its extension, nonlinear on "
        "SINDYc)",
        lambda: _mpc(models, data, out, quick, diag["commanded"]["result"]),
    )
    print(_render_mpc(mpc))
    camp = stages.run(
        f"campaign: the linear MPC on {CAMPAIGN_DRAWS} plant draws (friction, force lag, delay)",
        lambda: _campaign(data, out, quick, seed, progress),
    )
    print(_render_campaign(camp))
    summary = {
        "seed": seed,
        "quick": quick,
        "plant": {"preset": "paper_like", "noise": True, "fmu": str(data["plant"])},
        "samples": {"train": data["train"].n_samples, "valid": data["valid"].n_samples},
        "table_1": table,
        "reconstruction": rec,
        "diagnosis": diag["commanded"]["summary"],
        "diagnosis_tensions": diag["tensions"]["summary"],
        "export": {k: (str(v) if isinstance(v, Path) else v) for k, v in exp.items()},
        "mpc": mpc,
        "campaign": camp,
        "stage_seconds": stages.times,
    }
    stages.run("write the report", lambda: _write_report(out, summary, figs2, diag, data))
    summary["total_seconds"] = time.perf_counter() - t0
    write_json(out / "summary.json", json.loads(json.dumps(summary, default=str)))  # strict JSON
    print(f"Report: {out / 'index.html'}  (total {summary['total_seconds']:.0f} s)")
    return summary


def _fig2(data: dict[str, Any], out: Path) -> list[Path]:
    rec = data["recordings"]["train_circles"]
    return list(
        fig2(
            rec.columns, out / "figures", ee_ref=rec.protocol.ee_ref, title="identification circles"
        )
    )


def _mpc(
    models: dict[str, Any], data: dict[str, Any], out: Path, quick: bool, diagnosis: Any
) -> dict[str, Any]:
    """The controllers on the petal; the linear MPC also on the N4SID model as the diagnosis
    extended it, when a cause was named and the extension is linear (a delay, a lag)."""
    ref = make_reference("petal", duration=15.0 if quick else 40.0)
    plant = data["plant"]
    # The tuned defaults of the co-simulation (tendonkit.robot.controllers.DEFAULTS): Q = 1e4, R = 0.3,
    # horizon 20, and each antagonistic pair's sum held at 2 x 105 N.
    results = {
        "open-loop kinematic": open_loop(plant, ref),
        "linear MPC (N4SID)": run(plant, ref, make_controller(models["n4sid"]), name="linear MPC"),
    }
    note = "no cause named: the N4SID model is not extended"
    if diagnosis.cause != "none":
        # The linear MPC takes linear blocks (delays, lags); a rate limit found with a lag (the
        # force controller's carriage speed) is an actuator limit it leaves out, as it leaves
        # out the tendons' saturation.
        ext = diagnosis.extended
        kept = tuple(b for b in ext.input_blocks if b.kind in LINEAR_BLOCKS)
        left = sorted({b.kind for b in ext.input_blocks if b.kind not in LINEAR_BLOCKS})
        name = f"linear MPC (N4SID + {', '.join(diagnosis.causes)})"
        try:
            ctrl = make_controller(ext.replace(input_blocks=kept))
        except TendonkitError as exc:  # a nonlinear extension: the linear MPC cannot use it
            note = f"the extended N4SID model is not run: {exc}"
        else:
            results[name] = run(plant, ref, ctrl, name="linear MPC, extended")
            note = f"{name}: the N4SID model as the diagnosis extended it" + (
                f", its linear blocks only ({', '.join(left)} left out: an actuator limit the "
                "linear MPC does not model)"
                if left
                else ""
            )
    results["nonlinear MPC (SINDYc)"] = run(
        plant, ref, make_controller(models["sindyc"]), name="nonlinear MPC"
    )
    summaries = {k: r.summary() for k, r in results.items()}
    figures = [str(p) for p in plot_tracking(results, out / "figures")]
    return {"reference": ref.name, "results": summaries, "figures": figures, "extended": note}


#: Plant draws of the demo's campaign.
CAMPAIGN_DRAWS = 24


def _campaign(
    data: dict[str, Any], out: Path, quick: bool, seed: int, progress: bool
) -> dict[str, Any]:
    """The linear MPC across plant draws around the paper-like plant (docs/campaigns.md)."""
    spec = spec_from_dict(
        {
            "campaign": {"name": "demo", "seed": seed, "draws": CAMPAIGN_DRAWS},
            "plant": {
                "preset": "paper_like",
                "effects": ["N"],
                "vary": {"friction_mu_k": "spec", "forcelag_tau": "spec", "delay_s": "spec"},
            },
            "controllers": [{"name": "linear MPC (N4SID)", "model": "n4sid.json"}],
            "references": [{"kind": "petal", "duration": 6.0 if quick else 30.0}],
            "criteria": {
                "require": ["rms_error_true_mrad <= 35", "fallbacks == 0", "bound_violations == 0"]
            },
        },
        base_dir=out,
        source="demo campaign",
    )
    res = run_campaign(
        spec, out / "campaign", plant_fmu=data["plant"], progress=progress, fresh=True
    )
    s = res.summary
    return {
        "runs": s["runs"],
        "passed": s["passed"],
        "pass_rate": s["pass_rate"],
        "criteria": s["criteria"],
        "worst": s["worst"][0],
        "distribution": s["controllers"]["linear MPC (N4SID)"]["metrics"]["rms_error_true_mrad"],
        "engine": s["timing"]["engine"],
        "workers": s["timing"]["workers"],
        "figures": s.get("figures", []),
        "report": str(out / "campaign" / "index.html"),
    }


def _render_campaign(c: dict[str, Any]) -> str:
    w = c["worst"]
    params = ", ".join(f"{k} = {v:.3g}" for k, v in w["parameters"].items())
    d = c["distribution"]
    return "\n".join(
        [
            f"Campaign ({c['runs']} plant draws, {c['engine']} with {c['workers']} worker(s)): "
            f"the linear MPC passed {c['passed']} of {c['runs']} ({100 * c['pass_rate']:.0f} %; "
            f"{', '.join(c['criteria'])})",
            f"  true RMS error median {d['median']:.1f} mrad, p95 {d['p95']:.1f}, max {d['max']:.1f}",
            f"  worst plant: run {w['run']}, {params}: {w['rms_error_true_mrad']:.1f} mrad"
            + (f" ({w['failed']})" if w["failed"] else ""),
        ]
    )


def _render_mpc(mpc: dict[str, Any]) -> str:
    lines = [
        "MPC on the petal (co-simulation with the plant FMU):",
        f"  {'controller':<36} {'RMS q1 [mrad]':>14} {'RMS q2 [mrad]':>14} {'EE [cm]':>8} {'solve med/p99 [ms]':>20} {'fallbacks':>9}",
    ]
    for name, s in mpc["results"].items():
        rms = s["rms_error_rad"]
        st = s.get("solve_time_ms")
        solve = f"{st['median']:.2f}/{st['p99']:.2f}" if st else "-"
        lines.append(
            f"  {name:<36} {1e3 * rms['q1']:>14.2f} {1e3 * rms['q2']:>14.2f} {s['mean_ee_error_cm']:>8.2f} {solve:>20} {s['fallbacks']:>9}"
        )
    lines.append(f"  ({mpc['extended']})")
    return "\n".join(lines)


def _write_report(
    out: Path,
    summary: dict[str, Any],
    figs2: list[Path],
    diag: dict[str, Any],
    data: dict[str, Any],
) -> Path:
    rep = Report("tendonkit demo — the paper's study on the embedded plant", out)
    rep.text(
        "Plant: the rolling-joint tendon robot FMU with the paper-like preset (tendon friction, "
        "force-controller lag with tendon coupling, 30 ms delay, horizontal mounting, 2 Hz camera "
        "low-pass) and sensor noise. Models map the commanded tendon forces u1..u4 to the base "
        "joint angles q1 (pan) and q2 (tilt)."
    )
    rep.heading("Data (paper Fig. 2)")
    s = summary["samples"]
    rep.text(
        f"Identification: circles and pseudo-random motion, {s['train']} samples; validation: another seed, radii 1.5/6.5/11.5 cm clockwise, {s['valid']} samples."
    )
    for f in figs2:
        rep.figure(
            f,
            "Identification circles: joint angles per plane, normalised, and the end-effector path.",
        )
    rep.heading("Table I — validation fit")
    t = summary["table_1"]
    rep.table(
        ["method", "fit q1 [%]", "fit q2 [%]", "mean [%]", "paper mean [%]"],
        [
            [r["model"], r["fit"]["q1"], r["fit"]["q2"], r["mean_fit"], r["paper_mean_fit"]]
            for r in t["models"]
        ],
    )
    rep.text(_render_table(t).splitlines()[-1], note=True)
    rep.heading("Reconstruction (paper Fig. 3 and 4)")
    rec = summary["reconstruction"]
    rep.table(
        ["ratio", "paper", "least squares", "extremes"],
        [
            [
                k,
                rec["paper_ratios"][k],
                rec["estimated_ratios"]["least_squares"][k],
                rec["estimated_ratios"]["extremes"][k],
            ]
            for k in ("q3", "q4", "q5", "q6")
        ],
    )
    rep.table(
        ["method", *[f"fit q{i} [%]" for i in range(1, 7)], "EE error [cm]"],
        [[n, *r["joint_fit"].values(), r["ee_error_cm"]] for n, r in rec["models"].items()],
    )
    for name, row in rec["models"].items():
        for f in row.get("figures", []):
            rep.figure(
                f, f"{name}: {'six joints' if 'joints' in Path(f).name else 'end-effector path'}"
            )
    rep.heading("Diagnosis of both halves of the actuation chain")
    rep.text(
        "The linear MPC's model (N4SID) from the commanded forces, where the force controllers' "
        "lag acts; and the best model from the measured tensions, where the tendons' friction "
        "acts. Each names what is significant on the validation data, in order, with its gain."
    )
    for d in (diag["commanded"], diag["tensions"]):
        rep.pre(_render_diagnosis(d))
        rep.text(f"Full diagnosis report with figures: {d['folder']}/index.html", note=True)
        rep.figure(
            out / d["folder"] / "outputs_before_after.png",
            f"Validation ({d['what']}): measured, baseline and extended model.",
        )
    rep.heading("FMU export")
    e = summary["export"]
    rep.text(
        f"{Path(e['path']).name}: fmpy validation problems: {len(e['problems'])}; largest difference to tendonkit's own simulation: {e['max_difference']:.2e}."
    )
    rep.heading("MPC on the petal (paper Fig. 5)")
    m = summary["mpc"]
    rep.table(
        [
            "controller",
            "RMS q1 [mrad]",
            "RMS q2 [mrad]",
            "mean EE error [cm]",
            "solve median [ms]",
            "solve p99 [ms]",
            "fallbacks",
            "bound violations",
        ],
        [
            [
                n,
                1e3 * r["rms_error_rad"]["q1"],
                1e3 * r["rms_error_rad"]["q2"],
                r["mean_ee_error_cm"],
                # the open-loop controller solves nothing: say so instead of NaN
                (r.get("solve_time_ms") or {}).get("median", "no solver"),
                (r.get("solve_time_ms") or {}).get("p99", "no solver"),
                r["fallbacks"],
                r["input_bound_violations"],
            ]
            for n, r in m["results"].items()
        ],
    )
    rep.text(m["extended"], note=True)
    for f in m["figures"]:
        rep.figure(f, "Joint tracking and end-effector path, reference vs achieved.")
    rep.heading("Campaign: the linear MPC across plant draws")
    c = summary["campaign"]
    rep.pre(_render_campaign(c))
    for f in c["figures"]:
        if "metric_vs" in f or "worst" in f:
            rep.figure(f, "Campaign: " + Path(f).stem.replace("_", " "))
    rep.text("Full campaign report: campaign/index.html; the table: campaign/runs.csv", note=True)
    rep.heading("Timing")
    rep.table(["stage", "seconds"], [[k, v] for k, v in summary["stage_seconds"].items()])
    return rep.write()
