"""Built-in effects that extend a model with blocks on its inputs or outputs.

The data are transformed the way the effect acts, the baseline identifier is run again on
them, and the block is attached to the model — so these extensions work for every identifier:

- ``input_delay``: a common extra delay of ``d`` samples on every input;
- ``dead_zone``: inputs below a threshold have no effect (tendon slack, motor dead band), or
  an input of one sign acts whole above it (a gate: a pump that starts at a voltage, as
  terms);
- ``saturation``: a clipped output (overflow, sensor range) or clipped inputs;
- ``actuator_lag``: a first-order lag, optionally rate-limited, between command and plant (or
  in a loop with the load: ``slew_lag`` terms of the input minus a weighted output);
- ``backlash``: play of a given width on the outputs (joint play between the driven and the
  measured part).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import (
    Context,
    Extension,
    ResidualAnalysis,
    atom_test,
    drop_samples,
    refit_with_input_blocks,
    simulate_all,
)
from tendonkit.errors import TendonkitError
from tendonkit.hookspecs import hookimpl
from tendonkit.metrics import fit
from tendonkit.plugins import _bodies
from tendonkit.plugins._arx_structure import PARSIMONY, cv_folds, held_out_or_inf
from tendonkit.schema import ARX, Block, Model
from tendonkit.simulate import aligned, initial_span, play_operator, simulate, simulate_dataset
from tendonkit.terms import Factor, Term


def _with_input_blocks(ctx: Context, blocks: Sequence[Block]) -> Callable[[Dataset], Model]:
    return refit_with_input_blocks(ctx.refit, blocks)


def _held_out_better(
    ctx: Context, richer: Callable[[Dataset], Model], leaner: Callable[[Dataset], Model]
) -> bool:
    """Whether the ``richer`` structure simulates held-out blocks of the training data better
    than the ``leaner`` one by more than the structure selection's parsimony margin (the
    blocked cross-validation of ``arx``'s orders: :func:`_arx_structure.held_out_error`).
    A richer structure fits its training data better by construction; held out, the extra
    parameters must earn their place.  False where the folds cannot be made (the leaner one
    is kept); a structure that cannot be fitted on a fold scores an infinite error."""
    window = max(10, initial_span(ctx.baseline) + 1)
    try:
        folds = cv_folds(ctx.train, window)
    except TendonkitError:
        return False
    rich, lean = (held_out_or_inf(build, folds, window) for build in (richer, leaner))
    return bool(rich * (1.0 + PARSIMONY) < lean)


def _between_values(a: np.ndarray, t: float) -> float:
    """``t``, or half-way to the next larger value of ``a`` where ``t`` is one of them (0.0
    where none is larger: no threshold leaves samples on both sides there)."""
    if not np.any(a == t):
        return t
    above = a[a > t]
    return 0.5 * (t + float(above.min())) if above.size else 0.0


def _single_inputs(
    ctx: Context,
    params: dict[str, Any],
    blocks: Sequence[Block],
    model: Model | None,
    score: float,
) -> tuple[dict[str, Any], Model | None, float]:
    """The chosen blocks on one input at a time, if one of those fits the training data better.

    An effect of one actuator among several (one motor's dead band, one valve's delay) is not
    an effect of all of them; the candidates put the same block on every input first, so this
    step only adds one candidate per input.
    """
    if model is None or len(blocks) < 2:
        return params, model, score
    singles = [({**params, "inputs": [b.signal]}, _with_input_blocks(ctx, [b])) for b in blocks]
    p1, m1, s1, _ = ctx.select(singles)
    return (p1, m1, s1) if m1 is not None and s1 > score else (params, model, score)


def _concentration(res: ResidualAnalysis, condition: str) -> dict[str, float]:
    return {c.output: c.ratio for c in res.concentration if c.condition == condition}


class InputDelay:
    """Transport delay between the inputs and the system."""

    name = "input_delay"
    cause = "input_delay"
    description = "Input delay: every input reaches the system d samples later."
    #: Every whole delay up to this is tried; longer ones on a coarse grid (:meth:`delays`).
    max_delay = 8
    #: Longest delay tried, in samples, and the share of the shortest experiment it may take.
    max_far_delay = 160
    far_share = 0.05
    #: Fractions of a sample tried around the best whole delay.
    fractions = (-0.75, -0.5, -0.25, 0.25, 0.5, 0.75)

    def extend(self, ctx: Context) -> Extension | None:
        """Extra delays of 1..max_delay samples on every input, then fractions around the best.

        A physical delay is rarely a whole number of samples; a fraction ``α`` of a sample
        on a zero-order-held input is the two-tap average ``(1-α) u[k-n] + α u[k-n-1]``
        (:func:`tendonkit.simulate.fractional_delay`).  Without it, a lag that rounds off
        the same edge can fit a 2.7-sample delay better than 2 or 3 whole samples.
        """

        def blocks_of(d: float) -> list[Block]:
            return [Block("delay", n, {"samples": float(d)}) for n in ctx.train.inputs]

        def candidate(d: float) -> tuple[dict[str, Any], Callable[[Dataset], Model]]:
            params = {"samples": d, "seconds": d * ctx.train.dt}
            return params, _with_input_blocks(ctx, blocks_of(d))

        grid = self.delays(ctx.train)
        whole = ctx.select([candidate(d) for d in grid])
        if whole[1] is None:
            return None
        best_d = whole[0]["samples"]
        if best_d > self.max_delay:
            # between the coarse grid's neighbours of the best delay, every whole delay
            i = grid.index(best_d)
            lo, hi = grid[i - 1] + 1, (grid[i + 1] if i + 1 < len(grid) else best_d + 1)
            fine = [d for d in range(lo, hi) if d != best_d]
            near = ctx.select([candidate(d) for d in fine])
            if near[2] > whole[2]:
                whole = near
                best_d = whole[0]["samples"]
        # at least one sample: a shorter delay of a zero-order-held input is a blend of two
        # samples, which is a detail of the sampling instant, not a transport delay
        fractions = [best_d + f for f in self.fractions if best_d + f >= 1]
        frac = ctx.select([candidate(d) for d in fractions])
        params, model, score = whole[:3] if frac[2] <= whole[2] else frac[:3]
        params, model, score = _single_inputs(
            ctx, params, blocks_of(params["samples"]), model, score
        )
        return ctx.extension(params, model, score, self.description)

    def delays(self, train: Dataset) -> list[int]:
        """Whole delays tried: 1..max_delay, then steps of 25 % as far as the data support.

        A slow process sampled fast has a dead time of tens of samples (measured: a two-tank
        process at 1 s with 12-30 samples); a fixed limit of 8 turned those into an
        ``actuator_lag``.  The limit is ``far_share`` of the shortest experiment (so that most
        of every record still relates an input to its output), at most ``max_far_delay``.
        """
        shortest = min(e.n_samples for e in train.experiments)
        limit = min(self.max_far_delay, int(self.far_share * shortest))
        out = list(range(1, self.max_delay + 1))
        d = self.max_delay
        while True:
            d = max(d + 1, round(d * 1.25))
            if d > limit:
                break
            out.append(d)
        return out

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
    description = (
        "Dead zone: the part of every input within a threshold of zero has no effect (or, a "
        "gate, an input of one sign has none below a threshold and acts whole above it)."
    )

    #: Shares of the samples that fall inside the dead zone, per input.
    quantiles = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3)
    #: Then shares between the best one and its neighbours (geometric steps of 2^±½, 2^±¼).
    refine = (-0.5, -0.25, 0.25, 0.5)

    def extend(self, ctx: Context) -> Extension | None:
        """Thresholds at low quantiles of ``|u|``: the kink is placed where data are.

        The zone is centred on the physical zero of each input.  For a signal of one sign (a
        tension, a pump voltage) it is one-sided: ``max(u - threshold, 0)``, slack below the
        threshold.  A threshold is only useful where some samples fall inside it, so the
        candidates put 0.5–30 % of the samples in the zone: per input (each input's own
        quantile), and one threshold for all inputs (a quantile of all inputs pooled — the
        physical case when the inputs are alike, such as four tendons that slacken at the same
        tension, whose samples are not distributed alike).  Then shares between the best one
        and its neighbours are tried: a threshold off by a few percent of the range leaves a
        kink where the system has none.  Then the gates (:meth:`_shaped`), kept where one fits
        the training data better than the best zone and simulates held-out blocks of them
        better than the same zone written as terms.
        """
        u = np.abs(ctx.train.u)

        def candidate(
            q: float, pooled: bool
        ) -> tuple[dict[str, Any], Callable[[Dataset], Model]] | None:
            th = np.full(u.shape[1], np.quantile(u, q)) if pooled else np.quantile(u, q, axis=0)
            blocks = [
                Block("dead_zone", n, {"threshold": float(th[m]), "center": 0.0})
                for m, n in enumerate(ctx.train.inputs)
                if th[m] > 0
            ]
            if not blocks:
                return None
            params = {"quantile": q, "common": pooled, "threshold": [float(t) for t in th]}
            return params, _with_input_blocks(ctx, blocks)

        kinds = (False, True) if u.shape[1] > 1 else (False,)
        coarse = ctx.select(
            c for q in self.quantiles for k in kinds if (c := candidate(q, k)) is not None
        )
        params, model, score = coarse[:3]
        if model is not None:
            q0, k0 = params["quantile"], params["common"]
            fine = [candidate(q0 * 2.0**e, k0) for e in self.refine if q0 * 2.0**e < 0.5]
            best = ctx.select([c for c in fine if c is not None])
            if best[2] > score:
                params, model, score = best[:3]
        gate = ctx.select(self._shaped(ctx, "gate"))
        if gate[1] is not None and model is None:  # no zone could be placed: the gate alone
            params, model, score = gate[:3]
        elif gate[1] is not None and gate[2] > score:
            # The gate's terms have free coefficients at every lag, which fit the training
            # data better whatever the shape: its shape must beat a zone's written the same
            # way, on held-out blocks of the training data.
            zone = ctx.select(self._shaped(ctx, "zone"))
            richer, leaner = ctx.builder_of(gate[1]), ctx.builder_of(zone[1])
            if richer and leaner and _held_out_better(ctx, richer, leaner):
                params, model, score = gate[:3]
        # Not one input at a time: above its threshold a dead zone is an offset of its input,
        # and an offset on one input is a constant load (on the robot, a dead zone on one
        # tendon gained as much as gravity on a horizontal mount: +1.6 to +2.9 points).
        return ctx.extension(params, model, score, self.description)

    def _shaped(
        self, ctx: Context, shape: str
    ) -> list[tuple[dict[str, Any], Callable[[Dataset], Model]]]:
        """Zones written as terms at every lag the model reads each input of one sign, beside
        its own ``u``, with a coefficient each: ``shape="gate"`` an input that does nothing
        below a threshold and acts whole above it, ``u·[u > t]`` (a pump that starts at a
        voltage, a valve that opens at a pressure), as ``u·sign(u - t)`` (``u·[u < -t]`` and
        ``u·sign(u + t)`` for a negative input); ``"zone"`` the continuous zone
        ``sign(u)·max(|u| - t, 0)``, the gate's rival written the same way.  The thresholds at
        :attr:`quantiles` of the input's samples on its side (the side most samples are on; a
        pump off at 0 V for a while is not below its start), moved half-way to the next
        larger value where the quantile is a value the input takes (a held or quantised
        input: ``sign(0)`` would half-gate every sample at it); ``threshold`` lists them per
        input, signed (0.0: not gated).  Terms read lags >= 1: an input read at lag 0
        (``nk = 0``) is gated from lag 1 on only, not at all when that is its only lag.

        A gate's output jumps at the threshold, which no continuous zone followed by the
        model's offset has: on two tanks whose pump starts at 4-4.6 V (``bench_diagnose_chain.py
        --plant tanks``) the zone lost to a curve, a clip or nothing on all 8 seeds, fast and
        slow; with the gate the dead zone is named on 4 of them.  Only inputs of one sign are
        gated: an actuator that starts at a level is a pump, a valve, a tendon's tension; an
        input of both signs (a force, a motor voltage) has a dead band that grows from zero,
        the zone block's (and its gates cost a diagnosis of Silverbox 1.8 s of 11 for nothing).
        """
        u = ctx.train.u
        out, seen = [], set()
        for q in self.quantiles:
            terms: list[Term] = []
            ths = []
            for m, n in enumerate(ctx.train.inputs):
                lags = _bodies.input_lags(ctx.baseline, m)
                side = 1.0 if np.mean(u[:, m] > 0) >= np.mean(u[:, m] < 0) else -1.0
                a = side * u[:, m]
                a = a[a > 0]  # on its side: a pump off at 0 V is not below its start
                th = _between_values(a, float(np.quantile(a, q))) if a.size else 0.0
                if _bodies.both_signs(u[:, m]) or not lags or not th > 0:
                    ths.append(0.0)
                    continue
                ths.append(side * th)
                for lag in lags:
                    if shape == "zone":
                        terms.append(Term((Factor(n, fn="dead_zone", lag=lag, param=th),)))
                        continue
                    gate = Factor(n, fn="sign", lag=lag, offset=side * th)
                    terms.append(Term((Factor(n, lag=lag), gate)))
            if terms and tuple(ths) not in seen:
                seen.add(tuple(ths))
                params = {"quantile": q, "structure": shape, "threshold": ths}
                out.append((params, ctx.with_terms(terms)))
        return out

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
        """Outputs clipped where the training data pile up at a level (a plateau).

        Without a plateau there is no clipped output to model.  The clip is placed after the
        model (a sensor range) or in its recursion (an overflowing store, ARX only); the
        dynamics are either the baseline's (identified on all samples) or identified again on
        the unclipped samples.
        """
        cands = []
        y = ctx.train.y
        lag = 10
        for j, name in enumerate(ctx.train.outputs):
            lower, upper = _plateau(y[:, j])
            if lower is None and upper is None:
                continue
            lo_v = -np.inf if lower is None else lower
            hi_v = np.inf if upper is None else upper
            base = {"where": "output", "signal": name, "lower": lower, "upper": upper}
            loops = [False, True] if isinstance(ctx.baseline.representation, ARX) else [False]
            for refit in (False, True):
                for in_loop in loops:
                    params = {**base, "in_loop": in_loop, "refit_unclipped": refit}
                    build = self._clipped_output(ctx, j, name, lo_v, hi_v, lag, refit)
                    if in_loop:
                        build = self._in_loop(build, j, name, lo_v, hi_v)
                    cands.append((params, build))
        return cands

    @staticmethod
    def _clipped_output(
        ctx: Context, j: int, name: str, lo_v: float, hi_v: float, lag: int, refit: bool
    ) -> Callable[[Dataset], Model]:
        """The baseline, or the baseline identified on the unclipped samples, then a clip."""

        def build(data: Dataset) -> Model:
            tol = 1e-6 * (float(np.ptp(data.y[:, j])) or 1.0)

            def clipped(e: Experiment) -> np.ndarray:
                return (e.y[:, j] >= hi_v - tol) | (e.y[:, j] <= lo_v + tol)

            model = (
                ctx.refit(drop_samples(data, clipped, min_length=lag + 5))
                if refit
                else ctx.baseline
            )
            big = 1e300
            block = Block("saturation", name, {"lower": max(lo_v, -big), "upper": min(hi_v, big)})
            return model.replace(output_blocks=(*model.output_blocks, block))

        return build

    @staticmethod
    def _in_loop(
        wiener: Callable[[Dataset], Model], j: int, name: str, lo_v: float, hi_v: float
    ) -> Callable[[Dataset], Model]:
        """A clipped *state*: the recursion continues from the clipped level (an overflow).

        A tank that overflows stays full while the inflow exceeds the outflow and starts to
        empty as soon as it does not; a clip after the model (Wiener) would instead hold the
        output until the unclipped response came back down.  For an ARX model,
        ``Σ A_i clip(y[k-i])`` is ``Σ A_i y[k-i]`` plus relu terms of the past outputs whose
        coefficients are tied to the ``A_i``: the model is identified on the unclipped
        samples (or kept) and the terms are added with those coefficients (nothing new is
        estimated).
        """

        def build(data: Dataset) -> Model:
            model = wiener(data)
            rep = model.representation
            if not isinstance(rep, ARX):  # pragma: no cover - guarded by the caller
                return model
            terms, coefs = [], []
            for i, Ai in enumerate(rep.A, start=1):
                if np.isfinite(hi_v):
                    terms.append(Term((Factor(name, fn="relu", lag=i, param=hi_v),)))
                    coefs.append(Ai[:, j])
                if np.isfinite(lo_v):
                    terms.append(Term((Factor(name, fn="relu", lag=i, scale=-1.0, param=-lo_v),)))
                    coefs.append(-Ai[:, j])
            if not terms:
                return model
            old = (
                rep.term_coefficients
                if rep.term_coefficients is not None
                else np.zeros((0, len(model.outputs)))
            )
            new = dataclasses.replace(
                rep,
                terms=(*rep.terms, *terms),
                term_coefficients=np.vstack([old, np.array(coefs)]),
            )
            return model.replace(representation=new)

        return build

    #: Input clips at these quantiles (and one minus them): a limit that binds now and then
    #: (1 %) up to one that binds on a third of the record (a valve or a pump at its stop).
    input_quantiles = (0.01, 0.025, 0.05, 0.1, 0.2, 0.3)
    #: Which ends of the range are clipped.  Not the lower end alone: for an input of one sign
    #: (a tension, a valve opening) ``max(u, c)`` is a dead zone ``max(u - c, 0)`` plus a
    #: constant, and on the robot's slack tendons it came within 0.05 points of the dead zone.
    input_sides = ("both", "upper")

    @staticmethod
    def _input_blocks(ctx: Context, q: float, sides: str = "both") -> list[Block]:
        u = ctx.train.u
        big = 1e300
        lo = np.quantile(u, q, axis=0) if sides != "upper" else np.full(u.shape[1], -big)
        hi = np.quantile(u, 1 - q, axis=0) if sides != "lower" else np.full(u.shape[1], big)
        return [
            Block("saturation", n, {"lower": float(lo[m]), "upper": float(hi[m])})
            for m, n in enumerate(ctx.train.inputs)
            if hi[m] > lo[m]
        ]

    def _input_candidates(
        self, ctx: Context, quantiles: Sequence[float] | None = None, sides: Sequence[str] = ()
    ) -> list[tuple[dict[str, Any], Callable[[Dataset], Model]]]:
        """Inputs clipped at one or both ends of their range, at quantiles of the data."""
        cands = []
        for q in self.input_quantiles if quantiles is None else quantiles:
            for side in sides or self.input_sides:
                blocks = self._input_blocks(ctx, q, side)
                if blocks and 0 < q < 0.5:
                    params = {"where": "inputs", "quantile": q, "sides": side}
                    cands.append((params, _with_input_blocks(ctx, blocks)))
        return cands

    def extend(self, ctx: Context) -> Extension | None:
        """Output clipping (at plateaus of the data) or input clipping candidates.

        A plateau of the training output — samples piled up at one exact level — is an output
        clip seen in the data: a clip on an input reaches the output through the dynamics,
        which do not hold it at one value.  Where the training output has one, the output
        clips are the candidates; elsewhere the input clips, the best of which is then tried
        on one input at a time.  (Choosing between the two by training fit alone let an input
        clip at the 30 % quantile win on the cascaded tanks, whose output overflows at 10 V for
        47 training samples, and the clip seen in the validation data was never tested.)
        """
        outputs = self._output_candidates(ctx)
        params, model, score, _ = ctx.select(outputs or self._input_candidates(ctx))
        if model is not None and params.get("where") == "inputs":
            blocks = self._input_blocks(ctx, params["quantile"], params["sides"])
            params, model, score = _single_inputs(ctx, params, blocks, model, score)
        return ctx.extension(params, model, score, self.description)

    def direct_test(self, ctx: Context, ext: Extension, valid: Dataset) -> dict[str, Any] | None:
        """Do the validation data pile up at the level the extension clips the output at?

        A clipped output is seen in the data, not only inferred from a better fit: the samples
        stay at the limit while the baseline's simulation (the output without a clip) moves
        (:func:`tendonkit.diagnose.clip.atom_test`).  The test is made on the *validation* output at
        the level chosen on the training data; with two clipped ends, each must be seen (the
        larger p-value).  Only for a clip added to the baseline's dynamics, which leaves the
        simulation unchanged until the clip acts, so that the gain is the clip's.  Input clips
        are not seen in the outputs: None.
        """

        params = ext.params
        names = ctx.baseline.output_names
        if params.get("where") != "output" or params.get("signal") not in names:
            return None
        if params.get("refit_unclipped"):
            # Re-identified dynamics differ from the baseline everywhere: the gain would not be
            # the clip's alone, so the clip seen in the data does not vouch for it.
            return None
        ends = [(s, params[s]) for s in ("upper", "lower") if params.get(s) is not None]
        if not ends:
            return None
        j = list(names).index(params["signal"])
        data = aligned(ctx.baseline, valid)
        y = data.y[:, j]
        free = simulate_all(ctx.baseline, valid)[:, j]
        judge = float(fit(y[:, None], free[:, None])[0])
        tests = [
            atom_test(y, level, side, reference=free, reference_fit=judge, u=data.u).to_dict()
            for side, level in ends
        ]
        said = "; ".join(
            f"{t['side']} clip level {t['level']:.6g}: {t['reason']}"
            if t["reason"]
            else f"{t['count']} samples at the {t['side']} clip level {t['level']:.6g} while "
            f"the model and the inputs move, at most {t['expected']:.2g} without a clip"
            + (f" (runs of {t['run']:.2g} samples counted as one)" if t["run"] > 1.5 else "")
            for t in tests
        )
        return {
            "statistic": "validation output samples at the clip level while the baseline's "
            "simulation and the inputs move, Poisson tail against the most a peak or a held level would put "
            "there (tendonkit.diagnose.clip.atom_test); every clipped end must be seen",
            "summary": f"{params['signal']}: {said}",
            "signal": params["signal"],
            "tests": tests,
            "p_value": max(float(t["p_value"]) for t in tests),
        }

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


#: Below this share of an output's spread, an output's response to an input is none at all
#: (:func:`_static_gains`).
SETTLE_FLOOR = 1e-6


def _static_gains(model: Model, data: Dataset) -> np.ndarray | None:
    """``K[j, m]``: how far output ``j`` of ``model`` settles per unit of input ``m``, from a
    step of half the input's spread at the data's mean input (simulated: any representation,
    terms included); None where an output does not settle or the simulation diverges.  An
    output that the input moves by less than ``SETTLE_FLOOR`` of the output's spread counts as
    settled whatever its tail does (a round-off coupling on a slow mode of another output is
    no plant that drifts)."""
    data = aligned(model, data)
    u, spread = data.u.mean(axis=0), data.u.std(axis=0)
    floor = SETTLE_FLOOR * data.y.std(axis=0)
    n = min(max(len(data.u), 200), 4000)
    base = simulate(model, np.tile(u, (n, 1)))
    if not np.all(np.isfinite(base)):
        return None
    K = np.zeros((base.shape[1], len(u)))
    for m in range(len(u)):
        if spread[m] <= 0:
            continue
        step = np.tile(u, (n, 1))
        step[:, m] += 0.5 * spread[m]
        y = simulate(model, step) - base
        tail = y[-n // 10 :]
        # every output settled: its last tenth moves by less than 1 % of where it is, or the
        # input moves it by less than the floor at all
        moving = np.ptp(tail, axis=0) > 0.01 * np.abs(tail).max(axis=0)
        if not np.all(np.isfinite(y)) or np.any(moving & (np.abs(y).max(axis=0) >= floor)):
            return None
        K[:, m] = y[-1] / (0.5 * spread[m])
    return K


def _moves(data: Dataset) -> list[np.ndarray]:
    """Each input's nonzero ``|change per sample|`` within experiments."""
    du = np.vstack([np.abs(np.diff(e.u, axis=0)) for e in data.experiments if e.n_samples > 1])
    return [du[du[:, m] > 0, m] for m in range(du.shape[1])]


def _step_sizes(data: Dataset, q: float, moves: list[np.ndarray] | None = None) -> np.ndarray:
    """The ``q`` quantile of each input's nonzero ``|change per sample|`` within experiments
    (a command held in steps changes on few samples: a rate at its zero quantile would hold
    the actuator still); 0 for an input that never changes.  ``moves``: :func:`_moves` of
    ``data``, computed once by a caller that asks for several quantiles."""
    moves = _moves(data) if moves is None else moves
    return np.array([float(np.quantile(mv, q)) if mv.size else 0.0 for mv in moves])


class ActuatorLag:
    """The actuator follows its command with a lag (and a rate limit)."""

    name = "actuator_lag"
    cause = "actuator_lag"
    description = (
        "Actuator lag: every input passes a first-order lag (time constant τ), optionally "
        "rate-limited, before it acts on the system; or the actuator's lag and rate limit act "
        "in a loop with the load (its force also follows an output: a force controller on a "
        "compliant transmission)."
    )

    #: Time constants tried, in samples (from one: a shorter lag of a zero-order-held input is a
    #: detail of the sampling instant, which the baseline's numerator represents).
    taus = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    #: Rate limits tried, as quantiles of each input's nonzero |change per sample|
    #: (:func:`_step_sizes`: a command held in steps would give limits of 0).
    rate_quantiles = (0.05, 0.2, 0.5, 0.8)
    #: Then the best rate times 2 to these powers.
    refine = (-0.5, -0.25, 0.25, 0.5)

    #: In a loop with the load: the share ``c`` of each input's static gain to its output that
    #: flows back into the actuator (``g = -c / K``), the lag's time constant (samples) and
    #: the step limit (a quantile of the command's nonzero steps: :func:`_step_sizes`) — tried
    #: on a coarse grid, then one coordinate at a time around the best.  ``c`` can exceed 1
    #: (a stiff spring on a soft load feeds back more than the input's static effect; a
    #: series-elastic actuator's is its spring over the load's stiffness, 2.5 to 25 on
    #: ``bench_diagnose_chain.py --plant sea``).  The first route's grid starts from loads up
    #: to the input's static effect (``loop_shares``), the second route's probe spans stiff
    #: springs (``probe_shares``, reaching 8; the pattern search goes beyond either).
    loop_shares = (0.25, 0.5, 1.0)
    probe_shares = (0.5, 2.0, 8.0)
    loop_taus = (4.0, 16.0)
    loop_quantiles = (0.2, 0.5)

    #: Share of the baseline's training misfit that the lag or rate limit on the inputs alone
    #: must remove for the loop with the load to be searched in full and used by the first
    #: route (:meth:`extend`; otherwise only the probe below runs).  The loop's terms (a state
    #: per input that the output feeds back into) are flexible enough to reshape other effects
    #: where no lag is there to refine: on the robot plant with no lag they gained +0.6 to
    #: +1.7 points for friction, play and a dead zone and +0.5 for the nominal plant with
    #: slack tendons (named actuator_lag), where the lag alone removed 0.5 to 4.4 % of the
    #: misfit; with a force-controller lag it removed 46 to 55 %.
    loop_support = 0.1
    #: The second route: the share of the misfit that the loop's step limit itself must remove
    #: (its gain over the best loop without a step limit, ``step_limit_gain``) where the
    #: inputs' lag does not show: a motor's speed limit inside a series-elastic actuator's
    #: force loop binds on the loop's state, not on the command (there the step limit removed
    #: 43 to 67 % of the misfit, the open-loop lag and rate limit under 4 %).  On the robot
    #: plant with friction, play, a dead zone or no effect the loop removed at most 18 % of
    #: the misfit.
    loop_limit_share = 0.25
    #: On both routes the step limit must earn this share of the loop's gain: after a pump
    #: curve on the two tanks a loop admitted by the first route (the lag on the inputs removed
    #: 19 % of the misfit; its grid then reached shares of 8) gained 2.2 training points, 2.0
    #: of them without its step limit — a linear reshaping, named actuator_lag as a second
    #: cause (:meth:`loop_used`).
    loop_limit_earns = 0.5
    #: Where the inputs' lag does not show, the grid is a probe (``probe_shares``, the first
    #: step quantile: 6 fits) and the pattern search runs only if its best removes this share
    #: of the misfit (0.11 to 0.41 on the series-elastic actuator's speed limit): the search
    #: costs tens of fits, on every ARX baseline and held-out fold.
    loop_probe = 0.1
    #: Pattern search around the best grid point: the share and the time constant by factors
    #: of these, the quantile by this step, until no neighbour is better (at most
    #: ``loop_rounds`` rounds).
    loop_factors = (2.0**0.5, 2.0)
    loop_step = 0.15
    loop_rounds = 4

    def extend(self, ctx: Context) -> Extension | None:
        """First-order lags, then rate limits alone and combined with the best lag, then the
        lag in a loop with the load (:meth:`_in_loop`) where the inputs' lag shows or the
        loop's step limit removes a share of the misfit by itself (``loop_limit_share``), and in
        either case earns at least half of the loop's gain.

        Two stages keep the search small: the time constant is chosen first (training
        simulation fit), then rate limits at quantiles of ``|Δu|`` are tried alone and after
        that lag.
        """
        dt = ctx.train.dt
        lags = []
        for tau in self.taus:
            pole = float(np.exp(-1.0 / tau))
            blocks = [Block("first_order_lag", n, {"pole": pole}) for n in ctx.train.inputs]
            lags.append(({"tau_s": tau * dt, "pole": pole}, blocks))
        p1, _, _, _ = ctx.select((p, _with_input_blocks(ctx, b)) for p, b in lags)
        best_lag = next((b for p, b in lags if p == p1), [])
        cands = []
        if best_lag:
            cands.append((p1, _with_input_blocks(ctx, best_lag)))
        moves = _moves(ctx.train)
        for q in self.rate_quantiles:
            rate = _step_sizes(ctx.train, q, moves)
            rblocks = [
                Block("rate_limit", n, {"rate": float(rate[m])})
                for m, n in enumerate(ctx.train.inputs)
                if rate[m] > 0
            ]
            if not rblocks:
                continue
            rp = {"rate_quantile": q, "rate_per_s": [float(r / dt) for r in rate]}
            cands.append(({**rp, "tau_s": 0.0}, _with_input_blocks(ctx, rblocks)))
            if best_lag:
                cands.append(({**rp, **p1}, _with_input_blocks(ctx, [*rblocks, *best_lag])))
        params, model, score, _ = ctx.select(cands)
        if model is not None and "rate_quantile" in params:
            # a rate limit acts on every sample where it binds, so its level matters more than
            # a lag's: refine it between the quantiles (steps of 2^±½, 2^±¼ of the rate)
            with_lag = best_lag if params.get("tau_s") else []
            rfine = []
            for e in self.refine:
                rate = np.asarray(params["rate_per_s"]) * dt * 2.0**e
                rblocks = [
                    Block("rate_limit", n, {"rate": float(rate[m])})
                    for m, n in enumerate(ctx.train.inputs)
                    if rate[m] > 0
                ]
                rp = {**params, "rate_per_s": [float(r / dt) for r in rate], "rate_step": e}
                rfine.append((rp, _with_input_blocks(ctx, [*rblocks, *with_lag])))
            best = ctx.select(rfine)
            if best[2] > score:
                params, model, score = best[:3]
        # the loop where the data show it: a lag or a rate limit on the inputs alone removes
        # `loop_support` of the baseline's training misfit (first route), or the loop's step
        # limit by itself removes `loop_limit_share` of it (second route)
        misfit = 100.0 - ctx.baseline_score
        shown = model is not None and score - ctx.baseline_score >= self.loop_support * misfit
        loop = self._in_loop(ctx, shown=shown, beat=score)
        limit = loop[0].get("step_limit_gain", -np.inf)
        gain = loop[2] - ctx.baseline_score
        if loop[1] is not None and loop[2] > score and self.loop_used(misfit, shown, gain, limit):
            params, model, score = loop[:3]
        return ctx.extension(params, model, score, self.description)

    def loop_used(self, misfit: float, shown: bool, gain: float, limit: float) -> bool:
        """Whether a loop that gains ``gain`` training points over a baseline of training
        misfit ``misfit``, ``limit`` of them its step limit's (``step_limit_gain``), is used:
        by the first route (``shown``: the lag on the inputs removed ``loop_support`` of the
        misfit) or the second (the step limit alone removes ``loop_limit_share`` of it), and on
        both only where the step limit earns ``loop_limit_earns`` of the gain — a loop that
        gains as much without its step limit (a linear loop) is linear dynamics the baseline's
        orders leave out, not an actuator's limit."""
        by_limit = limit >= self.loop_limit_share * misfit
        earned = limit >= self.loop_limit_earns * gain
        return bool((shown or by_limit) and earned)

    def _in_loop(
        self, ctx: Context, *, shown: bool, beat: float = -np.inf
    ) -> tuple[dict[str, Any], Model | None, float, list[Any]]:
        """Rate-limited lags whose actuator also feels the load: ``slew_lag`` terms.

        A force-controlled actuator (a tendon's tension loop, a series-elastic joint) drives a
        load that pushes back: the force it applies is the controller's state ``R`` plus the
        load's reaction ``g·y``, and the controller moves ``R`` toward ``u - g·y`` at a limited
        rate.  No block on the input alone follows that (it needs the output), and without the
        rate limit it is linear (the baseline absorbs it); with it, ``R`` is a ``slew_lag``
        factor of ``u - g·y`` in place of the force at each of the baseline's input lags:
        the force of sample ``k - nk - i`` is the state after the command of the sample
        before, the factor's value at lag ``nk + i + 1``.  ``g`` is scaled by the baseline's
        static gain ``K`` of the input on the output it moves most (relative to that output's
        spread): ``g = -c / K`` with ``c > 0``, the share of the input's effect that comes
        back through the load — a load that pushes back (a spring), never one that pulls the
        actuator on.  A coarse grid of ``c``, the time constant and the step limit (a quantile
        of the command's nonzero steps), then a pattern search (``c`` of every input together
        and of each on its own).  ARX baselines whose outputs settle (a static gain exists).
        Where the lag on the inputs alone did not show (``shown`` false), the grid is a probe
        (``probe_shares``, the first step quantile) and the search stops after it when its
        best removes less than ``loop_probe`` of the misfit.  Where the loop cannot be used
        (it does not beat ``beat``, the open-loop extension's score, or without ``shown`` its
        gain is under ``loop_limit_share`` of the misfit) the result has no
        ``step_limit_gain``; otherwise ``step_limit_gain`` is the loop's training gain over
        the best loop without a step limit (a linear lag, at the shares of both grids,
        ``loop_shares`` and ``probe_shares``, the time constants and the chosen ones; floored
        at the baseline's score), and
        ``linear_loop_gain`` that loop's own gain.
        """
        rep = ctx.baseline.representation
        none: tuple[dict[str, Any], Model | None, float, list[Any]] = ({}, None, -np.inf, [])
        if not isinstance(rep, ARX) or rep.nb == 0 or not ctx.train.outputs:
            return none
        if not np.isfinite(ctx.baseline_score):
            return none  # a baseline that diverges on its training data: no misfit to share
        train = aligned(ctx.baseline, ctx.train)
        K = _static_gains(ctx.baseline, train)
        if K is None:
            return none  # it drifts (an integrating plant): no static gain to scale the loop by
        ystd = np.maximum(train.y.std(axis=0), 1e-300)
        ustd = train.u.std(axis=0)
        ins, outs = list(train.inputs), list(train.outputs)
        moves = _moves(train)
        sizes = {0.5: _step_sizes(train, 0.5, moves)}  # step limits by quantile, each once
        steps = sizes[0.5]
        links = []
        for m in range(len(ins)):
            moved = np.abs(K[:, m]) * ustd[m] / ystd  # each output's move per input spread
            j = int(np.argmax(moved))
            # an input that moves no output (beyond the floor of _static_gains: a step of half
            # the input's spread moves it by moved/2 of its spread) has no load to feel
            if moved[j] > 2 * SETTLE_FLOOR and steps[m] > 0:
                links.append((m, j, float(K[j, m])))
        if not links:
            return none

        def candidate(
            c: tuple[float, ...], tau: float, q: float | None
        ) -> tuple[dict[str, Any], Any]:
            alpha = float(1.0 - np.exp(-1.0 / tau))
            if q is None:  # no rate limit: a linear lag in the loop
                rate = np.full(len(ins), np.inf)
            else:
                if q not in sizes:
                    sizes[q] = _step_sizes(train, q, moves)
                rate = sizes[q]
            weights = [-ci / k for ci, (_, _, k) in zip(c, links, strict=True)]
            terms = [
                Term(
                    (
                        Factor(
                            ins[m],
                            fn="slew_lag",
                            lag=rep.nk[m] + i + 1,
                            param=alpha,
                            param2=float(rate[m]),
                            minus=outs[j],
                            weight=w,
                        ),
                    )
                )
                for (m, j, _), w in zip(links, weights, strict=True)
                for i in range(rep.nb)
            ]
            params = {
                "in_loop": True,
                "loop_share": list(c),
                "tau_s": tau * ctx.train.dt,
                "rate_quantile": q,
                "loop": {
                    ins[m]: {"output": outs[j], "weight": w}
                    for (m, j, _), w in zip(links, weights, strict=True)
                },
            }
            return params, ctx.with_terms(terms)

        n = len(links)
        # a probe (no lag shown on the inputs) tries stiff springs, the first quantile
        shares = self.loop_shares if shown else self.probe_shares
        quantiles = self.loop_quantiles if shown else self.loop_quantiles[:1]
        grid = [((c,) * n, t, q) for c in shares for t in self.loop_taus for q in quantiles]
        best = ctx.select(candidate(*g) for g in grid)
        if best[1] is None:
            return none
        misfit = 100.0 - ctx.baseline_score
        if not shown and best[2] - ctx.baseline_score < self.loop_probe * misfit:
            return none  # no lag shows on the inputs and the loop's grid finds little either
        fc, ft = self.loop_factors
        for _ in range(self.loop_rounds):
            c = tuple(best[0]["loop_share"])
            t, q = best[0]["tau_s"] / ctx.train.dt, best[0]["rate_quantile"]
            near = [(tuple(x * f for x in c), t, q) for f in (fc, 1 / fc)]
            if n > 1:
                near += [
                    (tuple(x * f if i == m else x for i, x in enumerate(c)), t, q)
                    for m in range(n)
                    for f in (fc, 1 / fc)
                ]
            near += [(c, t * ft, q), (c, t / ft, q)]
            near += [(c, t, r) for r in (q - self.loop_step, q + self.loop_step) if 0 < r < 1]
            step = ctx.select(candidate(*g) for g in near)
            if not step[2] > best[2]:
                break
            best = step
        if not best[2] > beat or (
            not shown and best[2] - ctx.baseline_score < self.loop_limit_share * misfit
        ):
            return best  # it cannot be used (no step_limit_gain): the check below is not run
        # what the step limit itself adds: the best loop without one (a linear lag, scored
        # only: an infinite step is never handed on), at both grids' shares, the time constants
        # and the chosen ones (a linear loop may go unstable at one share and fit at another)
        chosen = (tuple(best[0]["loop_share"]), best[0]["tau_s"] / ctx.train.dt, None)
        every = sorted({*self.loop_shares, *self.probe_shares})
        linear = {chosen, *(((x,) * n, tt, None) for x in every for tt in self.loop_taus)}
        lin = ctx.select(candidate(*g) for g in linear)[2]
        best[0]["linear_loop_gain"] = float(lin - ctx.baseline_score)
        best[0]["step_limit_gain"] = float(best[2] - max(lin, ctx.baseline_score))
        return best

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Concentration of the residual just after input changes."""
        return {
            "statistic": "RMS residual after input changes / elsewhere",
            "value": _concentration(res, "after input changes"),
            "signal": "input rate of change",
        }


def _fit_output_play(ctx: Context, data: Dataset, widths: np.ndarray, refinements: int) -> Model:
    """Identify a model whose outputs pass a play of half-widths ``widths``.

    The driven signal is ``x = y + w·c`` with ``c`` in [-1, 1] the side of the gap in
    contact.  The measured ``y`` is noisy and a play narrower than the noise would flip its
    direction at random, so ``c`` is read from noise-free simulations instead: first from the
    direction of the baseline's free-run simulation, then ``refinements`` times from the
    current model's own simulation, ``c = (x̂ - play(x̂)) / w`` (which also ramps through the
    gap instead of jumping).  Each pass re-runs the baseline identifier on ``x``.
    """

    data = aligned(ctx.baseline, data)
    model = ctx.baseline
    safe = np.where(widths > 0, widths, 1.0)
    for it in range(refinements + 1):
        inner_model = model.replace(output_blocks=())
        sims = simulate_dataset(inner_model, data)
        exps = []
        for e, sim in zip(data.experiments, sims, strict=True):
            sim = np.where(np.isfinite(sim), sim, e.y)
            x = e.y.copy()
            for j in range(e.y.shape[1]):
                if it == 0:
                    c = _direction(sim[:, j], widths[j])
                else:
                    c = (sim[:, j] - play_operator(sim[:, j], widths[j])) / safe[j]
                x[:, j] = e.y[:, j] + widths[j] * c
            exps.append(dataclasses.replace(e, y=x))
        fitted = ctx.refit(data.with_experiments(exps))
        blocks = tuple(
            Block("play", n, {"width": float(widths[j])}) for j, n in enumerate(data.outputs)
        )
        model = fitted.replace(output_blocks=(*fitted.output_blocks, *blocks))
    return model


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
    """Play: the measured output moves only after the driving motion has crossed a gap."""

    name = "backlash"
    cause = "backlash"
    description = (
        "Backlash: a play operator of half-width w on every output (joint play between the "
        "driven and the measured part); or a dead band in the difference of two outputs (a "
        "coupling with a gap between two bodies)."
    )

    #: Half-widths tried, as fractions of each output's standard deviation.
    fractions = (0.01, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64)
    #: Refinements of the reconstructed driven signal (see :func:`_fit_output_play`).
    refinements = 2
    #: Half-widths of the gap in a coupling between two outputs, as fractions of the spread of
    #: their difference.
    between_fractions = (0.02, 0.05, 0.1, 0.2, 0.4)

    def extend(self, ctx: Context) -> Extension | None:
        """Play on every output, half-widths as fractions of each output's spread.

        The measured output is the play's output; the play's input (the driven part) is
        reconstructed, the baseline identifier is run on it and a ``play`` block is attached
        to the outputs (:func:`_fit_output_play`).  Play on *inputs* (a force dead band that
        reverses with the direction) is quasi-static Coulomb friction in a force
        transmission and belongs to ``coulomb_friction``.
        """
        cands: list[tuple[dict[str, Any], Callable[[Dataset], Model]]] = []
        ystd = ctx.train.y.std(axis=0)
        for frac in self.fractions:
            widths = frac * ystd

            def build(data: Dataset, widths: np.ndarray = widths) -> Model:
                return _fit_output_play(ctx, data, widths, self.refinements)

            params = {
                "where": "outputs",
                "width": [float(w) for w in widths],
                "fraction_of_std": frac,
            }
            cands.append((params, build))
        cands += self._between(ctx)
        # every pair together only where it earns its extra terms (_bodies.select_pairs)
        return _bodies.best_extension(ctx, cands, self.description)

    def _between(self, ctx: Context) -> list[tuple[dict[str, Any], Callable[[Dataset], Model]]]:
        """A gap in a coupling between two bodies whose positions are both outputs, on every
        pair (plugins/_bodies.py), each pair alone and every pair together: the coupling's
        force ``k·dead_zone(d, w) = k·d − k·sat(d, w)``, ``d = y_a − y_b``, whose linear part
        is the baseline's, so the term is ``sat(d, w)`` (a narrow gap's dead zone is almost
        ``d`` itself, a regressor too close to the outputs for a re-identified N4SID
        baseline).  Centred at the difference's mean, and at zero too where a static load
        moves the mean off it (:meth:`Pair.centres`)."""
        pairs = _bodies.screened_pairs(ctx)
        groups = [[(p, "mean", p.mean)] for p in pairs]
        groups += [[(p, "zero", 0.0)] for p in pairs if "zero" in p.centres()]
        if len(pairs) > 1:
            groups.append([(p, "mean", p.mean) for p in pairs])
        cands: list[tuple[dict[str, Any], Callable[[Dataset], Model]]] = []
        for group in groups:
            for frac in self.between_fractions:
                terms = [_bodies.pair_term(p, "sat", centre=c, param=frac) for p, _, c in group]
                between = [p.label for p, _, _ in group]
                params = {
                    "where": "between two outputs",
                    "between": between[0] if len(group) == 1 else between,
                    "about": group[0][1],
                    "fraction_of_std": frac,
                    "width": [frac * p.std for p, _, _ in group],
                    "terms": [t.label for t in terms],
                }
                cands.append((params, ctx.with_terms(terms)))
        return cands

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
