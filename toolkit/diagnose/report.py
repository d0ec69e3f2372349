"""The diagnose report: what the simulation gets wrong, the named cause, before and after."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..dataset import Dataset
from ..figures import (
    plot_correlation,
    plot_outputs,
    plot_ranking,
    plot_residual_vs,
)
from ..report import Report
from . import Diagnosis
from .engine import simulate_all
from .findings import between_text, evidence_notes, experiment_lead, reshaping_notes, runner_up_text


def explaining_signal(cause: str, data: Dataset, j: int) -> tuple[np.ndarray, str]:
    """The signal against which a cause's residual pattern shows, for output ``j``."""
    y = data.y[:, j]
    name = data.outputs[j]
    if cause in ("coulomb_friction", "backlash", "hysteresis"):
        v = np.zeros_like(y)
        v[3:] = (y[3:] - y[:-3]) / (3 * data.dt)
        return v, f"velocity of {name} [{name} units/s]"
    if cause in ("nonlinear_stiffness", "gravity", "saturation"):
        return y, f"{name} [output units]"
    if cause == "dead_zone":
        return np.min(np.abs(data.u), axis=1), "smallest |input| [input units]"
    if cause == "actuator_lag":
        return np.max(np.abs(np.diff(data.u, axis=0, prepend=data.u[:1])), axis=1) / data.dt, (
            "largest input rate [input units/s]"
        )
    return data.u[:, 0], f"{data.inputs[0]} [input units]"


def write_report(
    diagnosis: Diagnosis, valid: Dataset, folder: str | Path, model_path: str | None = None
) -> Path:
    """Write ``index.html`` with figures into ``folder`` and return its path."""

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    d = diagnosis.to_dict(model_path)
    rep = Report("tendonkit diagnose", folder)
    rep.heading("Cause")
    best = diagnosis.best
    if diagnosis.unfit:
        rep.text(f"Unfit for diagnosis: {diagnosis.unfit}")
    elif best is None:
        rep.text(
            "No candidate extension improved the validation fit significantly: cause 'none'. "
            "The baseline's errors are consistent with noise or with structure none of the "
            "registered effects explains."
        )
        for note in evidence_notes(d):
            rep.text(note[0].upper() + note[1:])
    else:
        rep.text(
            f"Named cause: {best.cause}{between_text(best.params)} ({best.description}). "
            "Validation fit "
            f"{d['baseline']['fit']:.2f} % -> {d['extended']['fit']:.2f} % "
            f"(gain as tested {best.gain:+.2f} points, adjusted p = {best.p_adjusted:.2g})."
        )
        if diagnosis.margin is not None:
            rep.text(f"Margin to the runner-up{runner_up_text(d)}: {diagnosis.margin:.2f} points.")
        for note in evidence_notes(d):
            rep.text(note[0].upper() + note[1:])
    if diagnosis.ambiguous:
        rep.text(
            f"{diagnosis.ambiguous['statement']} Experiment "
            f"{experiment_lead(diagnosis.ambiguous)}: {diagnosis.ambiguous['experiment']}"
        )
    if len(d["sequence"]) > 1:
        rep.heading("Sequence of causes")
        rep.text(
            "After a cause is named, its extended structure, refitted by least squares as the "
            "candidates are, is the baseline of the next step, which tries the effects of the "
            "other causes (a gain is the extension's as tested; the refined fit is its model "
            "refined by simulation error); the sequence stops at the first step where "
            "nothing more is significant, or where the cause named is not confirmed once both "
            "models are refined."
        )
        rep.table(
            [
                "step",
                "cause",
                "fit before [%]",
                "fit as tested [%]",
                "gain [pts]",
                "adjusted p",
                "fit refined [%]",
                "tie",
            ],
            [
                [
                    st["step"],
                    st["cause"]
                    if st["cause"] != "none"
                    else ("not confirmed" if st.get("stop") else "nothing more significant"),
                    st["fit_before"],
                    st.get("tested_fit", st["fit"]),
                    st["gain"],
                    st["p_adjusted"] if st["p_adjusted"] is not None else "",
                    st["fit"],
                    st["ambiguous"]["statement"] if st.get("ambiguous") else "",
                ]
                for st in d["sequence"]
            ],
        )
        for st in d["sequence"][1:]:
            for note in reshaping_notes(st):
                rep.text(f"Step {st['step']}, {note}.", note=True)
            if st["cause"] == "none" and st.get("stop"):
                rep.text(f"Step {st['step']}: {st['stop']}.", note=True)
        rep.text(
            f"Final model: fit {d['baseline']['fit']:.2f} % -> {d['extended']['fit']:.2f} % "
            f"(total gain {d['extended']['total_gain']:+.2f} points); causes: "
            + ", ".join(d["causes"])
            + "."
        )
    last = d["sequence"][-1] if d["sequence"] else None
    if last is not None and last["cause"] != "none" and last.get("stop"):
        # the sequence ended on a named step (its structure could not be carried on)
        rep.text(f"Step {last['step']}: {last['stop']}.", note=True)
    v = d.get("versus")
    if v and "fit" in v:
        rep.text(
            f"Against {v['method']} (default options, the same training and validation data): "
            f"fit {v['fit']:.2f} % -> final model {d['extended']['fit']:.2f} % "
            f"(gain {v['extended_gain']:+.2f} points)."
        )
    elif v:
        rep.text(f"Against {v['method']}: not identified ({v.get('error')}).")
    rep.heading("Ranking of candidate causes (validation data)")
    rows = [
        [
            f["cause"],
            "diverged" if f.get("diverged") else f["gain"],
            "diverged" if f.get("diverged") else f["relative_gain"] * 100,
            f.get("p_adjusted", f["p_value"]),
            "yes" if f["significant"] else "no",
            f["n_params"],
        ]
        for f in d["findings"]
    ]
    rep.table(
        [
            "cause",
            "gain [pts]",
            "error energy drop [%]",
            "adjusted p",
            "significant",
            "added parameters",
        ],
        rows,
    )
    rep.figure(
        plot_ranking(folder, d["findings"]),
        "Gain of each candidate on held-out data (a candidate whose simulation diverged is "
        "marked, not drawn to scale).",
    )
    if diagnosis.skipped:
        rep.text(
            "Not applicable: "
            + "; ".join(f"{s['effect']} ({s['reason']})" for s in diagnosis.skipped),
            note=True,
        )
    rep.heading("Measured vs simulated, before and after")
    sims: dict[str, Any] = {"baseline": simulate_all(diagnosis.baseline, valid)}
    if best is not None and best.model is not None:
        sims[f"extended ({best.cause})"] = simulate_all(best.model, valid)
    if len(diagnosis.causes) > 1:
        sims[f"final ({' + '.join(diagnosis.causes)})"] = simulate_all(diagnosis.extended, valid)
    t = np.concatenate([e.t - e.t[0] + (i * 0) for i, e in enumerate(valid.experiments)])
    t = np.arange(len(t)) * valid.dt
    rep.figure(
        plot_outputs(
            folder,
            "before_after",
            t,
            valid.y,
            sims,
            list(valid.outputs),
            title="Validation data: measured, baseline and extended model",
        ),
        "Validation experiments back to back (time runs on across experiments).",
    )
    rep.heading("Residuals")
    res = diagnosis.residuals
    conc = sorted(res.concentration, key=lambda c: -c.ratio)[:8]
    rep.table(
        ["where", "output", "RMS inside / outside", "share of samples [%]"],
        [[c.condition, c.output, c.ratio, 100 * c.fraction] for c in conc],
    )
    cause = best.cause if best is not None else "none"
    for j, name in enumerate(valid.outputs):
        sig, label = explaining_signal(cause, valid, j)
        r = np.nan_to_num(res.residual[:, j])
        rep.figure(
            plot_residual_vs(
                folder,
                name if cause == "none" else f"{name} against {label} ({cause})",
                sig,
                r,
                label,
                f"free-run residual of {name}",
            ),
            f"Residual of {name} against {label}"
            + ("" if cause == "none" else f", the signal that explains '{cause}'")
            + ".",
        )
        strongest = res.strongest.get(name, {})
        m = (
            list(valid.inputs).index(strongest["input"])
            if strongest.get("input") in valid.inputs
            else 0
        )
        rep.figure(
            plot_correlation(
                folder,
                res.lags,
                res.crosscorr[j, m],
                res.band,
                f"{name} vs {valid.inputs[m]}",
                f"Cross-correlation of one-step residual of {name} with {valid.inputs[m]}",
            ),
            f"Cross-correlation of the one-step residual of {name} with {valid.inputs[m]}: "
            "correlation outside the band at a lag is dynamics the model misses at that lag.",
        )
    rep.heading("Settings")
    rep.pre(str(d["settings"]))
    return rep.write()
