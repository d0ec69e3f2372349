"""Compare models on data: fit per output and mean (the paper's Table I), optionally more.

The result is plain data (JSON-ready): one entry per model with its fit per output, the mean
fit, and whatever an application adds per model through ``extras`` (the robot adds the fits of
the reconstructed joints and the end-effector error: :func:`tendonkit.robot.reconstruct.joint_extras`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .dataset import Dataset
from .errors import DataError
from .figures import (
    plot_band,
    plot_bode,
    plot_outputs,
    plot_singular_values,
    plot_structure_selection,
)
from .frequency import empirical_response, model_response
from .metrics import FitRow, fit, fit_table
from .predict import predict
from .schema import Model
from .simulate import aligned, divergence, read_whole, simulate
from .uncertainty import covariance, simulate_band

#: Per-model additions to a row of :func:`compare`: ``(model, data, sims, name) -> dict``.
RowExtras = Callable[[Model, Dataset, list[np.ndarray], str], dict[str, Any]]


def score(
    model: Model,
    data: Dataset,
    *,
    initial: str = "estimate",
    k: int | None = None,
    init_window: int | None = None,
) -> tuple[dict[str, float], list[np.ndarray]]:
    """Fit per output of ``model`` on every experiment of ``data`` (concatenated for the score).

    With ``init_window`` (the benchmarks' official protocol) the initial state comes from the
    first ``init_window`` samples of each experiment only, and the fit is computed on the
    samples after them.  Returns the fits and the simulated (or k-step predicted) outputs per
    experiment (whole experiments).
    """
    fits, _, sims = _score(model, data, initial=initial, k=k, init_window=init_window)
    return fits, sims


def rmse(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """Root-mean-square error per output, in the outputs' unit (not finite after a diverged
    run: NaN, or inf where the squares overflow)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.sqrt(np.mean((np.asarray(y) - np.asarray(y_hat)) ** 2, axis=0))


def _refuse_records_read_whole(model: Model, data: Dataset, initial: str) -> None:
    """Refuse records ``model`` reproduces from their own outputs (:func:`read_whole`)."""
    why = [(i, e, read_whole(model, len(e.y), initial)) for i, e in enumerate(data.experiments)]
    short = [(i, e, w) for i, e, w in why if w]
    if short:
        listed = ", ".join(f"{e.name or i} ({len(e.y)} samples)" for i, e, _ in short)
        raise DataError(
            f"model {model.name!r} {short[0][2]}, which leaves nothing to score in {listed}: "
            "give longer records."
        )


def _score(
    model: Model,
    data: Dataset,
    *,
    initial: str = "estimate",
    k: int | None = None,
    init_window: int | None = None,
) -> tuple[dict[str, float], dict[str, float], list[np.ndarray]]:
    data = aligned(model, data)
    sims = []
    for e in data.experiments:
        if k is None:
            sims.append(
                simulate(model, e.u, y=e.y, initial=initial, init_window=init_window)  # type: ignore[arg-type]
            )
        else:
            sims.append(predict(model, e.u, e.y, k=k))
    skip = init_window or 0
    too_short = [e.name or str(i) for i, e in enumerate(data.experiments) if len(e.y) <= skip]
    if too_short:
        raise DataError(
            f"init_window {skip} leaves no sample to score in experiment(s) {', '.join(too_short)}."
        )
    if init_window is None:
        _refuse_records_read_whole(model, data, initial if k is None else "predict")
    y = np.vstack([e.y[skip:] for e in data.experiments])
    y_hat = np.vstack([s[skip:] for s in sims])
    names = model.output_names
    f = fit(y, y_hat)
    r = rmse(y, y_hat)
    return (
        {n: float(v) for n, v in zip(names, f)},
        {n: float(v) for n, v in zip(names, r)},
        sims,
    )


def compare(
    models: Sequence[Model],
    data_files: Sequence[str | Path] | Dataset,
    *,
    names: Sequence[str] | None = None,
    initial: str = "estimate",
    k: int | None = None,
    time: str = "t",
    plot_dir: str | Path | None = None,
    extras: RowExtras | None = None,
    init_window: int | None = None,
) -> dict[str, Any]:
    """Score every model on the data; see the module docstring for the result's layout.

    ``plot_dir`` draws measured against simulated outputs (one PNG); ``extras`` adds entries to
    each model's row from its simulation (e.g. reconstructed joints, with figures of their own).
    ``init_window`` applies the benchmarks' protocol (see :func:`score`); each row also has the
    RMSE per output (``rmse``, in the output's unit) on the scored samples.
    """
    names = list(names) if names is not None else [m.name for m in models]
    rows: list[dict[str, Any]] = []
    problems: list[str] = []
    for name, model in zip(names, models):
        try:
            data = (
                data_files
                if isinstance(data_files, Dataset)
                else Dataset.from_csv(data_files, model.input_names, model.output_names, time=time)
            )
        except DataError as exc:
            problems.append(f"model {name}: " + "; ".join(exc.problems or [str(exc)]))
            continue
        fits, errors, sims = _score(model, data, initial=initial, k=k, init_window=init_window)
        row: dict[str, Any] = {
            "model": str(name),
            "method": model.provenance.identifier or model.kind,
            "kind": model.kind,
            "fit": fits,
            "mean_fit": float(np.mean(list(fits.values()))),
            "rmse": errors,
            "units": {s.name: s.unit for s in model.outputs},
        }
        at = divergence(np.vstack(sims), aligned(model, data).y)
        if at is not None:
            # A diverged run has no fit: say where it left the data's range instead.
            row.update(
                fit=dict.fromkeys(fits), mean_fit=None, rmse=dict.fromkeys(errors),
                diverged_at_sample=at,
            )  # fmt: skip
            rows.append(row)
            continue
        if extras is not None:
            row.update(extras(model, data, sims, str(name)))
        rows.append(row)
    if problems:
        raise DataError("The data do not fit the models:", problems)
    mode = "free run" if k is None else f"{k}-step prediction"
    result: dict[str, Any] = {
        "mode": mode,
        "initial": initial if k is None else None,
        "init_window": init_window,
        "models": rows,
    }
    if plot_dir is not None and models and len({tuple(m.output_names) for m in models}) == 1:
        data0 = (
            data_files
            if isinstance(data_files, Dataset)
            else Dataset.from_csv(
                data_files, models[0].input_names, models[0].output_names, time=time
            )
        )
        result["figures"] = plot_compare(models, names, data0, plot_dir, initial, init_window)
    return result


def render_compare(result: dict[str, Any]) -> str:
    """Plain-text rendering of :func:`compare`'s result."""
    rows = [
        FitRow(r["model"], r["method"], r["fit"])
        for r in result["models"]
        if r.get("diverged_at_sample") is None
    ]
    window = result.get("init_window")
    scored = f", initial state from the first {window} samples, scored after them" if window else ""
    text = [
        f"Fit [%] ({result['mode']}{scored}), 100 (1 - |y - ŷ| / |y - mean y|):",
        fit_table(rows),
    ]
    scored_rows = [r for r in result["models"] if r.get("rmse") and None not in r["rmse"].values()]
    if scored_rows:
        text.append("RMSE (output units):")
        for r in scored_rows:
            units = r.get("units", {})
            text.append(
                f"  {r['model']}: "
                + ", ".join(
                    f"{n} {_g(v)}{(' ' + units[n]) if units.get(n) else ''}"
                    for n, v in r["rmse"].items()
                )
            )
    text += [
        f"{r['model']}: diverged at sample {r['diverged_at_sample']} (its outputs left 10^6 "
        "times the data's range) — no fit"
        for r in result["models"]
        if r.get("diverged_at_sample") is not None
    ]
    extra = [r for r in result["models"] if "joint_fit" in r or "ee_error_cm" in r]
    for r in extra:
        parts = []
        if "joint_fit" in r:
            parts.append(", ".join(f"{j} {v:.1f}" for j, v in r["joint_fit"].items()))
        if "ee_error_cm" in r:
            parts.append(f"mean end-effector error {r['ee_error_cm']:.2f} cm")
        text.append(f"{r['model']}: " + "; ".join(parts))
    return "\n".join(text)


def _g(v: float) -> str:
    return f"{v:.4g}"


def plot_compare(
    models: Sequence[Model],
    names: Sequence[str],
    data: Dataset,
    plot_dir: str | Path,
    initial: str = "estimate",
    init_window: int | None = None,
) -> list[str]:
    """Figures of the comparison (PNG paths).

    - measured against simulated outputs of every model, as :func:`compare` scores them;
    - for a model whose identifier selected its structure, the candidates' errors against
      order (:func:`~tendonkit.figures.plot_structure_selection`);
    - for a model with a parameter covariance, its simulation with the 99 % band
      (:func:`~tendonkit.uncertainty.simulate_band`);
    - for linear models, their Bode plots over the data's spectral estimate
      (:mod:`tendonkit.frequency`).
    """
    sims: dict[str, np.ndarray] = {}
    model0 = models[0]
    for name, model in zip(names, models):
        _, s = score(model, data, initial=initial, init_window=init_window)
        sims[str(name)] = np.vstack(s)
    data0 = aligned(model0, data)
    t = np.concatenate([e.t for e in data0.experiments])
    units = [s.unit for s in model0.outputs]
    path = plot_outputs(Path(plot_dir), "compare", t, data0.y, sims, model0.output_names, units)
    paths = [str(path)]
    out = Path(plot_dir)
    for name, model in zip(names, models):
        table = model.provenance.details.get("candidates")
        if table:  # the identifier selected the structure: show how
            paths.append(str(plot_structure_selection(out, str(name), table)))
        sv = model.provenance.details.get("singular_values")
        if sv:  # a subspace model: the singular values its order was read from
            order = int(model.provenance.details.get("order", 0))
            paths.append(str(plot_singular_values(out, str(name), sv, order)))
        if covariance(model) is not None and initial in ("estimate", "zero", "model"):
            bands = [
                simulate_band(model, e.u, e.y, initial=initial, init_window=init_window)
                for e in data0.experiments
            ]
            y_hat = np.vstack([b[0] for b in bands])
            half = np.vstack([b[1] for b in bands])
            paths.append(
                str(plot_band(out, str(name), t, data0.y, y_hat, half, model0.output_names, units))
            )
    linear = [(str(n), m) for n, m in zip(names, models) if m.is_linear]
    if linear:
        try:
            freqs, G, _ = empirical_response(data0)
        except DataError:
            return paths  # too short for a spectral estimate
        responses = {n: model_response(m, freqs) for n, m in linear}
        paths.append(
            str(
                plot_bode(
                    out, "compare", freqs, G, responses, model0.input_names, model0.output_names
                )
            )
        )
    return paths
