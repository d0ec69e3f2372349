"""A campaign's summary, table, figures and HTML report (:func:`tendonkit.robot.campaign.run_campaign`).

Figures: the ranking metric against every varied plant parameter (one panel each, failed runs
marked), the distributions of the main metrics per controller, and the trajectories of each
controller's worst run (simulated again here: runs are deterministic).
"""

from __future__ import annotations

import csv
import itertools
import math
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import OutputError
from ..files import atomic_write, write_json
from ..report import Report
from .figures import plot_tracking

if TYPE_CHECKING:
    from .campaign import CampaignSpec

__all__ = ["render", "summarise", "write_csv", "write_outputs"]

#: Metrics whose distributions the summary and the figure give.
MAIN = ("rms_error_true_mrad", "ee_error_true_cm", "solve_p99_ms", "fallbacks")


def _finite(values: list[Any]) -> np.ndarray:
    a = np.asarray([float(v) for v in values], dtype=float)
    return a[np.isfinite(a)]


def _stats(values: list[Any]) -> dict[str, float] | None:
    a = _finite(values)
    if not len(a):
        return None
    return {
        "p5": float(np.percentile(a, 5)),
        "median": float(np.median(a)),
        "p95": float(np.percentile(a, 95)),
        "max": float(np.max(a)),
    }


def _worst(spec: CampaignSpec, rows: list[dict[str, Any]], k: int) -> list[dict[str, Any]]:
    """Runs that did not run first, then the largest values of the ranking metric."""

    def key(r: dict[str, Any]) -> tuple[int, float]:
        x = r[spec.rank_by]
        bad = r["status"] != "ok" or not math.isfinite(float(x))
        return (1 if bad else 0, float(x) if not bad else math.inf)

    out = []
    for r in sorted(rows, key=key, reverse=True)[:k]:
        out.append(
            {
                "run": r["run"],
                "controller": r["controller"],
                "reference": r["reference"],
                "status": r["status"],
                spec.rank_by: r[spec.rank_by],
                "parameters": {v.name: r[v.name] for v in spec.vary},
                "seed": r["seed"],
                "failed": r["failed"],
                "error": r["error"],
            }
        )
    return out


def write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    """The table as CSV (columns in the rows' order; NaN as empty), written atomically."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]

    def write(tmp: Path) -> None:
        with tmp.open("w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=columns)
            w.writeheader()
            for r in rows:
                w.writerow(
                    {k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()}
                )

    return atomic_write(path, write)


def summarise(
    spec: CampaignSpec,
    rows: list[dict[str, Any]],
    engine: dict[str, Any],
    resumed: int,
    metrics: tuple[str, ...],
) -> dict[str, Any]:
    """Pass rate, per-controller distributions, worst cases, retries and timing."""
    n = len(rows)
    passed = sum(bool(r["passed"]) for r in rows)
    per: dict[str, Any] = {}
    for c in spec.controllers:
        mine = [r for r in rows if r["controller"] == c.name]
        ok = sum(bool(r["passed"]) for r in mine)
        per[c.name] = {
            "runs": len(mine),
            "passed": ok,
            "pass_rate": ok / len(mine) if mine else 0.0,
            "metrics": {m: _stats([r[m] for r in mine]) for m in metrics},
            "worst": _worst(spec, mine, 1)[0] if mine else None,
        }
    status: dict[str, int] = {}
    for r in rows:
        status[r["status"]] = status.get(r["status"], 0) + 1
    run_s = _finite([r["wall_s"] for r in rows])
    wall = engine.get("wall_s", 0.0)
    now = engine.get("runs_now", 0)
    return {
        "name": spec.name,
        "runs": n,
        "passed": passed,
        "pass_rate": passed / n if n else 0.0,
        "min_pass_rate": spec.min_pass_rate,
        "campaign_passed": (passed / n if n else 0.0) >= spec.min_pass_rate,
        "criteria": [str(c) for c in spec.criteria],
        "rank_by": spec.rank_by,
        "plan": {
            "sampling": spec.sampling,
            "draws": spec.n_draws,
            "repeats": spec.repeats,
            "references": [r.name for r in spec.references],
            "controllers": [c.name for c in spec.controllers],
            "varied": [v.name for v in spec.vary],
            "preset": spec.preset,
            "effects": list(spec.effects),
            "seed": spec.seed,
        },
        "controllers": per,
        "worst": _worst(spec, rows, 5),
        "status": status,
        "retried": [
            {"run": r["run"], "attempts": r["attempts"]} for r in rows if r["attempts"] > 1
        ],
        "errors": [{"run": r["run"], "error": r["error"]} for r in rows if r["status"] == "error"],
        "resumed": resumed,
        "timing": {
            **engine,
            "mean_run_s": float(np.mean(run_s)) if len(run_s) else None,
            "runs_per_hour": 3600.0 * now / wall if wall > 0 and now else None,
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        },
    }


def render(summary: dict[str, Any]) -> str:
    """The summary as the CLI prints it."""
    s = summary
    lines = [
        f"campaign {s['name']}: {s['passed']} of {s['runs']} runs passed "
        f"({100 * s['pass_rate']:.0f} %; required {100 * s['min_pass_rate']:.0f} %)"
        + (f"; criteria: {', '.join(s['criteria'])}" if s["criteria"] else ""),
    ]
    rank = s["rank_by"]
    for name, c in s["controllers"].items():
        st = c["metrics"][rank]
        dist = (
            f"{rank} median {st['median']:.3g}, p95 {st['p95']:.3g}, max {st['max']:.3g}"
            if st
            else "no finished run"
        )
        lines.append(f"  {name}: {c['passed']}/{c['runs']} passed; {dist}")
    for w in s["worst"][:3]:
        params = ", ".join(f"{k}={_fmt(v)}" for k, v in w["parameters"].items()) or "nominal"
        what = w["failed"] or "passed"
        value = w[rank]
        shown = (
            f"{rank} {value:.3g}"
            if isinstance(value, float) and math.isfinite(value)
            else w["status"]
        )
        lines.append(
            f"  worst: run {w['run']} ({w['controller']}, {w['reference']}): {shown} at {params}; {what}"
        )
    if s["retried"]:
        lines.append(
            f"  retried after a worker died: {len(s['retried'])} run(s) "
            f"({', '.join(str(r['run']) for r in s['retried'][:10])})"
        )
    if s["errors"]:
        lines.append(
            f"  runs that raised: {len(s['errors'])} (first: run {s['errors'][0]['run']}: {s['errors'][0]['error']})"
        )
    t = s["timing"]
    rate = f", {t['runs_per_hour']:.0f} runs/hour" if t.get("runs_per_hour") else ""
    resumed = f"; {s['resumed']} rows resumed from an earlier run" if s["resumed"] else ""
    lines.append(
        f"  engine {t['engine']} ({t['workers']} worker(s)): {t['runs_now']} runs in {t['wall_s']:.1f} s{rate}{resumed}"
    )
    return "\n".join(lines)


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def write_outputs(
    spec: CampaignSpec,
    out: Path,
    rows: list[dict[str, Any]],
    summary: dict[str, Any],
    shared: dict[str, Any],
    payloads: list[dict[str, Any]],
    simulate: Callable[[dict[str, Any], dict[str, Any]], Any],
    report: bool = True,
) -> None:
    """``runs.csv``, ``summary.json`` and (``report``) ``figures/`` and ``index.html``."""
    try:
        write_csv(out / "runs.csv", rows)
        write_json(out / "summary.json", summary)  # before anything that simulates again
        figures: list[tuple[Path, str]] = []
        if report:
            folder = out / "figures"
            folder.mkdir(exist_ok=True)
            figures += _parameter_figure(spec, rows, folder)
            figures += _distribution_figure(spec, rows, folder)
            figures += _worst_figures(summary, shared, payloads, simulate, folder)
            summary["figures"] = [str(p) for p, _ in figures]
            write_json(out / "summary.json", summary)
            _html(spec, out, summary, figures)
    except OSError as exc:
        raise OutputError(f"Cannot write the campaign's outputs in {str(out)!r}: {exc}") from None


def _canvas(w: float, h: float) -> Any:
    # lazy: heavy (matplotlib)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]


def _parameter_figure(
    spec: CampaignSpec, rows: list[dict[str, Any]], folder: Path
) -> list[tuple[Path, str]]:
    varied = [v for v in spec.vary if all(isinstance(r[v.name], int | float) for r in rows)]
    if not varied:
        return []
    cols = min(len(varied), 3)
    nrows = -(-len(varied) // cols)
    fig = _canvas(4.3 * cols, 3.3 * nrows)
    axes = fig.subplots(nrows, cols, squeeze=False)
    rank = spec.rank_by
    for ax, v in zip(axes.flat, varied):
        for c, color in zip(spec.controllers, itertools.cycle(COLORS)):
            mine = [r for r in rows if r["controller"] == c.name]
            x = np.array([float(r[v.name]) for r in mine])
            y = np.array([float(r[rank]) for r in mine])
            ok = np.array([bool(r["passed"]) for r in mine])
            ax.scatter(x[ok], y[ok], s=14, color=color, label=c.name, alpha=0.8)
            if np.any(~ok):
                ax.scatter(
                    x[~ok], y[~ok], s=30, color=color, marker="x", label=f"{c.name} (failed)"
                )
        for crit in spec.criteria:
            if crit.metric == rank:
                ax.axhline(crit.value, color="k", ls="--", lw=1)
        ax.set_xlabel(v.name + (" (log)" if v.log else ""))
        if v.log:
            ax.set_xscale("log")
        ax.set_ylabel(rank)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(varied) :]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"{spec.name}: {rank} against the drawn plant parameters (x: failed run)")
    path = folder / "metric_vs_parameters.png"
    fig.savefig(path, dpi=110)
    return [
        (
            path,
            f"{rank} of every run against each drawn plant parameter; crosses are failed runs, the dashed line the criterion.",
        )
    ]


def _distribution_figure(
    spec: CampaignSpec, rows: list[dict[str, Any]], folder: Path
) -> list[tuple[Path, str]]:
    metrics = [spec.rank_by] + [m for m in MAIN if m != spec.rank_by]
    fig = _canvas(4.0 * len(metrics), 3.2)
    axes = fig.subplots(1, len(metrics), squeeze=False)[0]
    for ax, m in zip(axes, metrics):
        for c, color in zip(spec.controllers, itertools.cycle(COLORS)):
            a = _finite([r[m] for r in rows if r["controller"] == c.name])
            if len(a):
                ax.hist(a, bins=min(30, max(5, len(a) // 3)), alpha=0.55, color=color, label=c.name)
        ax.set_xlabel(m)
        ax.set_ylabel("runs")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    path = folder / "distributions.png"
    fig.savefig(path, dpi=110)
    return [(path, "Distributions of the main metrics per controller.")]


def _worst_figures(
    summary: dict[str, Any],
    shared: dict[str, Any],
    payloads: list[dict[str, Any]],
    simulate: Callable[[dict[str, Any], dict[str, Any]], Any],
    folder: Path,
) -> list[tuple[Path, str]]:
    out = []
    for k, (name, c) in enumerate(summary["controllers"].items()):
        w = c.get("worst")
        if not w or w["status"] != "ok":
            continue
        try:
            res = simulate(shared, payloads[w["run"]])
        except Exception as exc:  # a run that passed once in a worker: report, don't crash
            summary.setdefault("figure_problems", []).append(
                f"run {w['run']} could not be simulated again for its figure: "
                f"{type(exc).__name__}: {exc}"
            )
            continue
        sub = folder / f"worst_{k}"
        [png] = plot_tracking({f"run {w['run']}: {name}": res}, sub)
        path = folder / f"worst_{k}_tracking.png"
        os.replace(png, path)
        shutil.rmtree(sub, ignore_errors=True)
        params = ", ".join(f"{p}={_fmt(v)}" for p, v in w["parameters"].items()) or "nominal plant"
        out.append(
            (
                path,
                f"Worst run of {name}: run {w['run']} ({w['reference']}; {params}; seed {w['seed']}).",
            )
        )
    return out


def _html(
    spec: CampaignSpec, out: Path, s: dict[str, Any], figures: list[tuple[Path, str]]
) -> Path:
    rep = Report(f"tendonkit campaign — {spec.name}", out)
    plan = s["plan"]
    rep.text(
        f"{s['runs']} runs: {plan['draws']} plant draws ({plan['sampling']}, seed {plan['seed']}) × "
        f"{plan['repeats']} noise seed(s) × {len(plan['references'])} reference(s) × "
        f"{len(plan['controllers'])} controller(s). Plant: preset {plan['preset']}, effects "
        f"{', '.join(plan['effects']) or 'none'}; drawn: {', '.join(plan['varied']) or 'nothing'}."
    )
    rep.heading("Pass rate")
    rep.text(
        f"{s['passed']} of {s['runs']} runs passed ({100 * s['pass_rate']:.1f} %, required "
        f"{100 * s['min_pass_rate']:.0f} %): the campaign {'passed' if s['campaign_passed'] else 'FAILED'}. "
        f"Criteria: {', '.join(s['criteria']) or 'none (a run passes when it ran)'}."
    )
    rank = s["rank_by"]
    rows = []
    for name, c in s["controllers"].items():
        st = c["metrics"][rank] or {}
        rows.append(
            [
                name,
                c["runs"],
                c["passed"],
                100 * c["pass_rate"],
                st.get("median", "-"),
                st.get("p95", "-"),
                st.get("max", "-"),
            ]
        )
    rep.table(
        ["controller", "runs", "passed", "pass rate [%]", f"{rank} median", "p95", "max"], rows
    )
    rep.heading("Worst cases")
    rep.table(
        ["run", "controller", "reference", rank, "parameters", "seed", "failed"],
        [
            [
                w["run"],
                w["controller"],
                w["reference"],
                w[rank] if w["status"] == "ok" else w["status"],
                ", ".join(f"{k}={_fmt(v)}" for k, v in w["parameters"].items()) or "nominal",
                w["seed"],
                w["failed"] or w["error"] or "passed",
            ]
            for w in s["worst"]
        ],
    )
    for path, caption in figures:
        rep.figure(path, caption)
    rep.heading("Engine")
    t = s["timing"]
    rep.text(
        f"{t['engine']} with {t['workers']} worker(s): {t['runs_now']} runs in {t['wall_s']:.1f} s"
        + (f" ({t['runs_per_hour']:.0f} runs/hour)" if t.get("runs_per_hour") else "")
        + (f"; mean run {t['mean_run_s']:.2f} s" if t.get("mean_run_s") else "")
        + (f"; {s['resumed']} rows resumed" if s["resumed"] else "")
        + f"; retried after a worker died: {len(s['retried'])}; runs that raised: {len(s['errors'])}."
    )
    rep.text("The table: runs.csv (one row per run); the summary: summary.json.", note=True)
    return rep.write()
