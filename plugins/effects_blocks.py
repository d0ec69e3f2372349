"""Built-in effects that extend a model with blocks on its inputs or outputs.

The data are transformed the way the effect acts, the baseline identifier is run again on
them, and the block is attached to the model — so these extensions work for every identifier:

- ``input_delay``: a common extra delay of ``d`` samples on every input;
- ``dead_zone``: inputs below a threshold have no effect (tendon slack, motor dead band);
- ``saturation``: a clipped output (overflow, sensor range) or clipped inputs;
- ``actuator_lag``: a first-order lag, optionally rate-limited, between command and plant;
- ``backlash``: play of a given width on the outputs (joint play) or on the inputs (gears).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tendonkit.augment import drop_samples, transform_inputs, transform_outputs
from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import Context, Extension
from tendonkit.hookspecs import hookimpl
from tendonkit.residuals import ResidualAnalysis
from tendonkit.schema import Block, Model


def _with_input_blocks(ctx: Context, blocks: Sequence[Block]) -> Callable[[Dataset], Model]:
    def build(data: Dataset) -> Model:
        model = ctx.refit(transform_inputs(data, blocks))
        return model.replace(input_blocks=(*blocks, *model.input_blocks))

    return build


def _select_and_finish(
    ctx: Context, effect: Any, cands: list[tuple[dict[str, Any], Callable[[Dataset], Model]]]
) -> Extension | None:
    if not cands:
        return None
    params, model, score, _ = ctx.select(cands)
    if model is None:
        return None
    return Extension(
        model=model,
        params=params,
        description=effect.description,
        train_gain=score - ctx.baseline_score,
    )


def _concentration(res: ResidualAnalysis, condition: str) -> dict[str, float]:
    return {c.output: c.ratio for c in res.concentration if c.condition == condition}


class InputDelay:
    """Transport delay between the inputs and the system."""

    name = "input_delay"
    cause = "input_delay"
    description = "Input delay: every input reaches the system d samples later."
    max_delay = 8

    def extend(self, ctx: Context) -> Extension | None:
        """Try extra delays 1..max_delay samples on every input."""
        cands = []
        for d in range(1, self.max_delay + 1):
            blocks = [Block("delay", n, {"samples": float(d)}) for n in ctx.train.inputs]
            cands.append(
                ({"samples": d, "seconds": d * ctx.train.dt}, _with_input_blocks(ctx, blocks))
            )
        return _select_and_finish(ctx, self, cands)

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Lag of the strongest input correlation of the one-step residuals."""
        return {
            "statistic": "lag of the strongest residual-input correlation",
            "value": {k: v["lag"] for k, v in res.strongest.items()},
            "correlation": {k: v["correlation"] for k, v in res.strongest.items()},
            "signal": "inputs at the lag of strongest correlation",
        }


class DeadZone:
    """Inputs below a threshold do nothing (slack tendons, a motor's dead band)."""

    name = "dead_zone"
    cause = "dead_zone"
    description = "Dead zone: the part of every input within a threshold of zero has no effect."

    def extend(self, ctx: Context) -> Extension | None:
        """Thresholds at quantiles of |u| over all inputs."""
        u = np.abs(ctx.train.u)
        cands = []
        for q in (0.02, 0.05, 0.1, 0.2, 0.3):
            th = float(np.quantile(u, q))
            if th <= 0:
                continue
            blocks = [
                Block("dead_zone", n, {"threshold": th, "center": 0.0}) for n in ctx.train.inputs
            ]
            cands.append(({"threshold": th, "quantile": q}, _with_input_blocks(ctx, blocks)))
        return _select_and_finish(ctx, self, cands)

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """RMS residual when some input is small relative to the rest."""
        u = np.abs(valid.u)
        low = np.any(u <= np.quantile(u, 0.1, axis=0), axis=1)
        r = res.residual
        ratio = (
            {
                n: float(
                    np.sqrt(np.mean(r[low, j] ** 2)) / (np.sqrt(np.mean(r[~low, j] ** 2)) + 1e-300)
                )
                for j, n in enumerate(valid.outputs)
            }
            if low.any() and (~low).any()
            else {}
        )
        return {
            "statistic": "RMS residual at small |input| / elsewhere",
            "value": ratio,
            "signal": "smallest |input|",
        }


def _plateau(
    y: np.ndarray, tol_frac: float = 1e-6, min_frac: float = 0.005
) -> tuple[float | None, float | None]:
    """Levels at which the output piles up (clipping), if any."""
    rng = float(np.ptp(y)) or 1.0
    tol = tol_frac * rng + 1e-12
    n = len(y)
    need = max(3, int(min_frac * n))
    hi = float(np.max(y))
    lo = float(np.min(y))
    upper = hi if np.sum(y >= hi - tol) >= need else None
    lower = lo if np.sum(y <= lo + tol) >= need else None
    return lower, upper


class Saturation:
    """A signal limited to a range: output overflow or sensor range, or clipped inputs."""

    name = "saturation"
    cause = "saturation"
    description = (
        "Saturation: an output clipped at a level (identified on the unclipped samples) or inputs "
        "clipped to a range."
    )

    def _output_candidates(
        self, ctx: Context
    ) -> list[tuple[dict[str, Any], Callable[[Dataset], Model]]]:
        cands = []
        y = ctx.train.y
        lag = 10
        for j, name in enumerate(ctx.train.outputs):
            lower, upper = _plateau(y[:, j])
            levels = []
            if lower is not None or upper is not None:
                levels.append((lower, upper, "plateau"))
            for q in (0.99, 0.97):
                levels.append((None, float(np.quantile(y[:, j], q)), f"quantile {q}"))
            for lo, hi, how in levels:
                lo_v = -np.inf if lo is None else lo
                hi_v = np.inf if hi is None else hi
                params = {
                    "where": "output",
                    "signal": name,
                    "lower": lo,
                    "upper": hi,
                    "level_from": how,
                }
                cands.append((params, self._clipped_output(ctx, j, name, lo_v, hi_v, lag)))
        return cands

    @staticmethod
    def _clipped_output(
        ctx: Context, j: int, name: str, lo_v: float, hi_v: float, lag: int
    ) -> Callable[[Dataset], Model]:
        """Identify on the unclipped samples, then clip the model's output at the levels."""

        def build(data: Dataset) -> Model:
            tol = 1e-6 * (float(np.ptp(data.y[:, j])) or 1.0)

            def clipped(e: Experiment) -> np.ndarray:
                return (e.y[:, j] >= hi_v - tol) | (e.y[:, j] <= lo_v + tol)

            model = ctx.refit(drop_samples(data, clipped, min_length=lag + 5))
            big = 1e300
            block = Block("saturation", name, {"lower": max(lo_v, -big), "upper": min(hi_v, big)})
            return model.replace(output_blocks=(*model.output_blocks, block))

        return build

    def _input_candidates(
        self, ctx: Context
    ) -> list[tuple[dict[str, Any], Callable[[Dataset], Model]]]:
        cands = []
        u = ctx.train.u
        for q in (0.01, 0.025):
            lo = np.quantile(u, q, axis=0)
            hi = np.quantile(u, 1 - q, axis=0)
            blocks = [
                Block("saturation", n, {"lower": float(lo[m]), "upper": float(hi[m])})
                for m, n in enumerate(ctx.train.inputs)
                if hi[m] > lo[m]
            ]
            if blocks:
                cands.append(({"where": "inputs", "quantile": q}, _with_input_blocks(ctx, blocks)))
        return cands

    def extend(self, ctx: Context) -> Extension | None:
        """Output clipping (plateaus or high quantiles) and input clipping candidates."""
        return _select_and_finish(
            ctx, self, self._output_candidates(ctx) + self._input_candidates(ctx)
        )

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Share of samples piled up at the output extremes."""
        out = {}
        for j, n in enumerate(valid.outputs):
            lo, hi = _plateau(valid.y[:, j])
            y = valid.y[:, j]
            share = 0.0
            if hi is not None:
                share += float(np.mean(y >= hi - 1e-6 * np.ptp(y)))
            if lo is not None:
                share += float(np.mean(y <= lo + 1e-6 * np.ptp(y)))
            out[n] = share
        return {
            "statistic": "share of output samples at a plateau",
            "value": out,
            "large_output_concentration": _concentration(res, "large |output|"),
            "signal": "output level",
        }


class ActuatorLag:
    """The actuator follows its command with a lag (and a rate limit)."""

    name = "actuator_lag"
    cause = "actuator_lag"
    description = (
        "Actuator lag: every input passes a first-order lag (time constant τ), optionally "
        "rate-limited, before it acts on the system."
    )

    def extend(self, ctx: Context) -> Extension | None:
        """Time constants of 0.5..8 samples, with and without rate limits at |Δu| quantiles."""
        dt = ctx.train.dt
        du = np.abs(np.diff(ctx.train.u, axis=0))
        cands = []
        for tau in (0.5, 1.0, 2.0, 3.0, 5.0, 8.0):
            pole = float(np.exp(-1.0 / tau))
            blocks = [Block("first_order_lag", n, {"pole": pole}) for n in ctx.train.inputs]
            cands.append(({"tau_s": tau * dt, "pole": pole}, _with_input_blocks(ctx, blocks)))
            if tau in (1.0, 3.0, 5.0):
                for q in (0.5, 0.8):
                    rate = np.quantile(du, q, axis=0)
                    rblocks = [
                        Block("rate_limit", n, {"rate": float(rate[m])})
                        for m, n in enumerate(ctx.train.inputs)
                        if rate[m] > 0
                    ]
                    if rblocks:
                        params = {
                            "tau_s": tau * dt,
                            "pole": pole,
                            "rate_quantile": q,
                            "rate_per_s": [float(r / dt) for r in rate],
                        }
                        cands.append((params, _with_input_blocks(ctx, [*rblocks, *blocks])))
        return _select_and_finish(ctx, self, cands)

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Concentration of the residual just after input changes."""
        return {
            "statistic": "RMS residual after input changes / elsewhere",
            "value": _concentration(res, "after input changes"),
            "signal": "input rate of change",
        }


def _direction(y: np.ndarray, width: float) -> np.ndarray:
    """Direction of motion held between reversals larger than ``width`` (+1/-1)."""
    d = np.ones_like(y)
    ref = y[0]
    cur = 1.0
    for k, v in enumerate(y):
        if v > ref + width:
            cur, ref = 1.0, v
        elif v < ref - width:
            cur, ref = -1.0, v
        elif (cur > 0 and v > ref) or (cur < 0 and v < ref):
            ref = v
        d[k] = cur
    return d


class Backlash:
    """Play: the output (or input) moves only after the motion has crossed a gap."""

    name = "backlash"
    cause = "backlash"
    description = (
        "Backlash: a play operator of half-width w on every output (joint play between the "
        "driven and the measured part) or on every input (gear play)."
    )

    def extend(self, ctx: Context) -> Extension | None:
        """Play widths as fractions of each signal's standard deviation."""
        cands: list[tuple[dict[str, Any], Callable[[Dataset], Model]]] = []
        ystd = ctx.train.y.std(axis=0)
        for frac in (0.01, 0.02, 0.04, 0.08):
            widths = frac * ystd

            def build(data: Dataset, widths: np.ndarray = widths) -> Model:
                def unplay(y: np.ndarray) -> np.ndarray:
                    out = y.copy()
                    for j in range(y.shape[1]):
                        out[:, j] = y[:, j] + widths[j] * _direction(y[:, j], widths[j])
                    return out

                model = ctx.refit(transform_outputs(data, unplay))
                blocks = tuple(
                    Block("play", n, {"width": float(widths[j])})
                    for j, n in enumerate(data.outputs)
                )
                return model.replace(output_blocks=(*model.output_blocks, *blocks))

            cands.append(
                (
                    {
                        "where": "outputs",
                        "width": [float(w) for w in widths],
                        "fraction_of_std": frac,
                    },
                    build,
                )
            )
        ustd = ctx.train.u.std(axis=0)
        for frac in (0.01, 0.03):
            blocks = [
                Block("play", n, {"width": float(frac * ustd[m])})
                for m, n in enumerate(ctx.train.inputs)
                if ustd[m] > 0
            ]
            cands.append(
                ({"where": "inputs", "fraction_of_std": frac}, _with_input_blocks(ctx, blocks))
            )
        return _select_and_finish(ctx, self, cands)

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Concentration of the residual near reversals of the motion."""
        return {
            "statistic": "RMS residual near velocity reversals / elsewhere",
            "value": _concentration(res, "near velocity reversals"),
            "signal": "direction of motion",
        }


@hookimpl
def tendonkit_register_effects(registry):  # type: ignore[no-untyped-def]
    """Register the block-based effects."""
    for effect in (InputDelay(), DeadZone(), Saturation(), ActuatorLag(), Backlash()):
        registry.add(effect)
