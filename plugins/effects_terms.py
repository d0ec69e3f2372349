"""Built-in effects that extend a model with nonlinear terms of its past outputs (and inputs).

- ``coulomb_friction``: ``tanh(Δ_m y[k-1] / ε)`` per output — a smoothed sign of the velocity
  (with ``tanh²`` for asymmetric friction) — or a play on every input (friction in a force
  transmission is a dead band in force space that follows the direction of motion);
- ``nonlinear_stiffness``: odd powers ``y[k-1]^3`` (and ``^5``), or ``tanh(y[k-1]/s)``, per output;
- ``gravity``: a constant (operating-point load) and ``cos(y[k-1])`` for angle outputs;
- ``hysteresis``: a hysteresis operator of the past output — a Bouc-Wen state
  ``bouc_wen(y[k-1])`` or a play ``play(y[k-1])`` (a restoring force with a memory of the
  path, carried from step to step by every simulator);
- ``static_nonlinearity``: a curve of the past *inputs* (Hammerstein: ``u²``, ``u³`` or
  ``|u|`` at every input lag), a polynomial output block after the dynamics (Wiener) or a
  curve between two filters (Wiener–Hammerstein) — no powers of past outputs, which would be
  nonlinear dynamics.

Each effect proposes a few structures and scales, fits each on the training data with
:func:`tendonkit.diagnose.extend.extend_with_terms` (which works for every representation) and keeps
the one with the best training simulation fit (:meth:`tendonkit.diagnose.Context.select`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from tendonkit.dataset import Dataset
from tendonkit.diagnose import (
    Context,
    Extension,
    ResidualAnalysis,
    extend_with_terms,
    fit_wiener,
    refit_with_input_blocks,
)
from tendonkit.errors import TendonkitError
from tendonkit.hookspecs import hookimpl
from tendonkit.identification import without_training_fit
from tendonkit.output_error import free_parameters
from tendonkit.plugins import _bodies
from tendonkit.plugins._arx_structure import PARSIMONY as ARX_PARSIMONY
from tendonkit.plugins._arx_structure import as_tuple as _as_tuple
from tendonkit.plugins._arx_structure import cv_folds, cv_window, held_out_or_inf
from tendonkit.plugins._bla_split import best_split
from tendonkit.plugins.arx import ARX as ArxOptions
from tendonkit.schema import ARX, Block, Model, StateSpace
from tendonkit.simulate import transform_inputs
from tendonkit.terms import Factor, Term


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


_velocity = _bodies.velocity


#: ``build(train) -> Model``: a candidate structure fitted on some data.
Builder = Callable[[Dataset], Model]
#: An effect's candidates: ``(params, build)`` each.
Candidates = list[tuple[dict[str, Any], Builder]]


class _TermEffect:
    """Shared logic: candidates of term sets, selection on the check part, refit."""

    name = ""
    cause = ""
    description = ""

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        raise NotImplementedError

    def builders(self, ctx: Context) -> Candidates:
        """Every candidate as ``(params, build(train) -> Model)``."""
        return _labelled(ctx, self.candidates(ctx))

    def extend(self, ctx: Context) -> Extension | None:
        """Choose the candidate with the best training simulation fit; every pair of outputs
        together only where it earns its extra terms (:func:`_bodies.select_pairs`)."""
        return _bodies.best_extension(ctx, self.builders(ctx), self.description)


def _labelled(ctx: Context, candidates: list[tuple[dict[str, Any], list[Term]]]) -> Candidates:
    """Term candidates as ``(params with the terms' labels, build)``."""
    return [
        ({**p, "terms": [t.label for t in terms]}, ctx.with_terms(terms)) for p, terms in candidates
    ]


class CoulombFriction(_TermEffect):
    """Coulomb (dry) friction: a force of constant size opposing the direction of motion."""

    name = "coulomb_friction"
    cause = "coulomb_friction"
    description = (
        "Coulomb friction: adds tanh(velocity/ε) of every output (a smoothed sign of the "
        "direction of motion), with tanh² for asymmetric friction (Fc+ ≠ Fc-), or a narrow "
        "play of every output (the direction held while the output stands still); or, for "
        "friction in a force transmission, a play (dead band that follows the direction) on "
        "every input."
    )
    #: Half-widths of the input play, as fractions of each input's standard deviation.
    play_fractions = (0.01, 0.02, 0.04, 0.08, 0.16)
    #: Share of the training misfit that the force reversing with the motion must remove,
    #: beyond a constant load, before an asymmetry (tanh²) is tried.
    support_share = 0.05
    #: Quantile of |output| that sets ε of the friction on an output that is itself a speed.
    #: Only a sharp sign: a smooth tanh(y/ε) (ε at the 20 % quantile, half a standard
    #: deviation) is a softening spring of a *position* output as much as a friction of a
    #: speed, and it named friction for a weight's torque on the generic oscillator (gravity
    #: at dt 0.01, +0.88 points); nonlinear_stiffness tries those smooth curves.
    speed_quantiles = (0.02,)
    #: Velocity spans (samples) of the friction between two outputs.
    relative_spans = (1, 3, 8)
    #: Half-widths (fractions of the output's standard deviation) of the play that holds the
    #: direction of motion at rest: ``y - play(y)`` is ``±w`` while the output moves and keeps
    #: its last sign while it does not (:meth:`candidates`).  No wider: a play of 0.15 std or
    #: more is an elastic range, the hysteresis effect's.  No narrower either: at 0.02 std it
    #: took the robot's horizontal mount from gravity (+2.8 against +2.7 on four of six seeds).
    direction_widths = (0.05,)

    def extend(self, ctx: Context) -> Extension | None:
        """Friction proper first; its asymmetry only if a reversing force is supported.

        The asymmetric part ``tanh²(v/ε)`` is 1 while the system moves and 0 at rest, so on
        a record that is nearly always moving it is a constant load — gravity's structure (a
        weight on a link that moves by small angles gained +5.0 points as gravity and +5.0 as
        "asymmetric friction").  What sets friction apart is the force that reverses with the
        direction of motion.  So the asymmetric candidates are tried only when ``tanh(v/ε)``
        removes ``support_share`` of the training misfit that a constant load leaves (the
        test is made with the constant, because a system that integrates — EMPS, a drive in
        position control — drifts with a symmetric friction alone when its friction is not).
        """
        terms_of = self.candidates(ctx)
        cands = self._with_play(ctx, _labelled(ctx, terms_of))
        proper = [c for c in cands if not c[0].get("asymmetric")]
        asym = [c for c in cands if c[0].get("asymmetric")]
        params, model, score, _ = ctx.select(proper)
        if asym:
            const: list[Term] = [Term()]
            _, _, s0, _ = ctx.select([({}, ctx.with_terms(const))])
            with_const = [
                (p, ctx.with_terms([*const, *terms]))
                for p, terms in terms_of
                if not p.get("asymmetric")
            ]
            _, _, s1, _ = ctx.select(with_const)
            if 100.0 - s1 <= (1.0 - self.support_share) * (100.0 - s0):
                p2, m2, s2, _ = ctx.select(asym)
                if m2 is not None and s2 > score:
                    params, model, score = p2, m2, s2
        return ctx.extension(params, model, score, self.description)

    def builders(self, ctx: Context) -> Candidates:
        """Velocity-sign terms, and play on the inputs (quasi-static friction in force space).

        Static friction along a transmission (a tendon over capstans, a cable in a sheath, a
        gear train with friction) passes a change of the driving force only after the
        force has moved by the friction band since the last reversal: a play operator in
        force space, of width set by the friction force.  Rate-independent, it shows in a
        slow quasi-static experiment where ``sign(velocity)`` terms of a dynamic model do
        not.
        """
        return self._with_play(ctx, super().builders(ctx))

    def _with_play(self, ctx: Context, cands: Candidates) -> Candidates:
        """``cands`` and the play-on-the-inputs candidates after them."""
        ustd = ctx.train.u.std(axis=0)
        for frac in self.play_fractions:
            blocks = [
                Block("play", n, {"width": float(frac * ustd[m])})
                for m, n in enumerate(ctx.train.inputs)
                if ustd[m] > 0
            ]
            if blocks:
                params = {
                    "where": "inputs",
                    "structure": "play in force space",
                    "fraction_of_std": frac,
                    "width": [b.params["width"] for b in blocks],
                }
                cands.append((params, refit_with_input_blocks(ctx.refit, blocks)))
        return cands

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        out: list[tuple[dict[str, Any], list[Term]]] = []
        y = ctx.train.y
        for m in (1, 3, 8, 20):
            if 4 * m >= min(e.n_samples for e in ctx.train.experiments):
                continue
            vel = np.abs(_velocity(y, m))
            for q in (0.02, 0.2):
                eps = np.quantile(vel, q, axis=0)
                eps = np.where(eps > 0, eps, np.max(vel, axis=0) * 1e-3 + 1e-12)
                terms = [
                    Term((Factor(name, fn="tanh", lag=1, diff=m, scale=float(1.0 / eps[j])),))
                    for j, name in enumerate(ctx.train.outputs)
                ]
                params = {
                    "structure": "sign of velocity",
                    "velocity_span": m,
                    "epsilon": [float(e) for e in eps],
                }
                out.append(({**params, "asymmetric": False}, terms))
                # Asymmetric friction (Fc+ ≠ Fc-): tanh² is |sign(velocity)| while moving and
                # zero at rest, so the asymmetry is not a constant load (that is gravity's).
                sq = [Term((t.factors[0], t.factors[0])) for t in terms]
                out.append(({**params, "asymmetric": True}, [*terms, *sq]))
        # The direction of motion held at rest: a play of the output narrower than any elastic
        # range.  A joint that sticks (a spring against the friction band) stands still, and
        # the sign of a measured velocity there is the sign of the noise; the play keeps the
        # last direction until the output has moved back by 2 w.  On a two-axis tendon joint
        # with Coulomb friction against its spring (2 % noise; benchmarks/
        # bench_diagnose_pantilt.py) friction by the one-sample velocity's sign gained +3.9 /
        # +6.4 points and the hysteresis effect's plays, whose weight sat on the narrowest
        # (0.05 std), +4.4 / +6.9: hysteresis was named on both seeds (now on one).
        mu = y.mean(axis=0)
        sd = np.where(y.std(axis=0) > 0, y.std(axis=0), 1.0)
        for w in self.direction_widths:
            terms = [
                Term((Factor(name, fn="play", lag=1, scale=float(1.0 / sd[j]),
                             offset=float(mu[j]), param=w),))
                for j, name in enumerate(ctx.train.outputs)
            ]  # fmt: skip
            held: dict[str, Any] = {
                "structure": "sign of velocity, held at rest (a narrow play of the output)",
                "half_width_in_std": w,
                "asymmetric": False,
            }
            out.append((held, terms))
        # Friction between two bodies whose positions are both outputs (a joint's bearing, a
        # slipping clutch): the sign of their relative velocity (plugins/_bodies.py)
        for pair in _bodies.screened_pairs(ctx):
            rel = _bodies.difference(y, ctx.train.outputs, pair.a, pair.b)
            for m in self.relative_spans:
                if 4 * m >= min(e.n_samples for e in ctx.train.experiments):
                    continue
                vel = np.abs(_velocity(rel, m))
                eps = float(np.quantile(vel, 0.02)) or float(np.max(vel)) * 1e-3 + 1e-12
                term = Term((Factor(pair.a, fn="tanh", lag=1, diff=m, minus=pair.b,
                                    scale=1.0 / eps),))  # fmt: skip
                params = {
                    "structure": "sign of relative velocity",
                    "between": pair.label,
                    "velocity_span": m,
                    "epsilon": [eps],
                    "asymmetric": False,
                }
                out.append((params, [term]))
        # An output that is itself a speed (a tachometer, a flow): the friction force follows
        # the sign of the output, not of its difference.  Only for outputs that reverse (a
        # speed of one sign has no sign to follow).
        reverses = [_bodies.both_signs(y[:, j]) for j in range(y.shape[1])]
        if any(reverses):
            for q in self.speed_quantiles:
                eps = np.quantile(np.abs(y), q, axis=0)
                eps = np.where(eps > 0, eps, np.max(np.abs(y), axis=0) * 1e-3 + 1e-12)
                terms = [
                    Term((Factor(name, fn="tanh", lag=1, scale=float(1.0 / eps[j])),))
                    for j, name in enumerate(ctx.train.outputs)
                    if reverses[j]
                ]
                params = {
                    "structure": "sign of the output (a speed)",
                    "epsilon": [float(e) for e in eps],
                    "asymmetric": False,
                }
                out.append((params, terms))
        return out

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the validation residual with the direction of motion."""
        y = valid.y
        corr = {
            n: _corr(res.residual[:, j], np.sign(_velocity(y[:, j], 3)))
            for j, n in enumerate(valid.outputs)
        }
        rev = {
            c.output: c.ratio for c in res.concentration if c.condition == "near velocity reversals"
        }
        return {
            "statistic": "corr(residual, sign(velocity))",
            "value": corr,
            "reversal_concentration": rev,
            "signal": "sign of the output velocity",
        }


class NonlinearStiffness(_TermEffect):
    """Amplitude-dependent stiffness: hardening or softening springs (Duffing-type)."""

    name = "nonlinear_stiffness"
    cause = "nonlinear_stiffness"
    description = (
        "Nonlinear stiffness: adds odd powers y^3 (and y^5), or tanh(y/s), of every output: a "
        "hardening or softening spring; or the cube of the difference of two outputs: a "
        "hardening coupling between two bodies."
    )

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        y = ctx.train.y
        mu = y.mean(axis=0)
        sd = np.where(y.std(axis=0) > 0, y.std(axis=0), 1.0)
        outs: list[tuple[dict[str, Any], list[Term]]] = []
        # A spring is odd about its rest position: the mean of the output, or its zero when
        # the output is measured from rest (an odd power about the mean is not odd about zero:
        # its even part would be left for another effect to pick up).
        lo, hi = y.min(axis=0), y.max(axis=0)
        centres = {"mean": mu}
        if np.all((lo < 0) & (hi > 0)):
            centres["zero"] = np.zeros_like(mu)
        for centre, c in centres.items():
            for powers in ((3,), (3, 5)):
                terms = [
                    Term(
                        (Factor(name, power=p, lag=1, scale=float(1 / sd[j]), offset=float(c[j])),)
                    )
                    for p in powers
                    for j, name in enumerate(ctx.train.outputs)
                ]
                params = {"structure": "odd powers", "powers": list(powers), "about": centre}
                outs.append((params, terms))
        # A spring whose stiffness changes and then levels off (softening that saturates, or a
        # stop): tanh of the output at a few scales.  Bounded, so a softening fit cannot make
        # the simulation run away the way a negative cubic does at large amplitude.
        for c in (0.5, 1.0, 2.0):
            terms = [
                Term(
                    (
                        Factor(
                            name,
                            fn="tanh",
                            lag=1,
                            scale=float(1 / (c * sd[j])),
                            offset=float(mu[j]),
                        ),
                    )
                )
                for j, name in enumerate(ctx.train.outputs)
            ]
            outs.append(({"structure": "tanh", "scale_in_std": c}, terms))
        # A spring between two bodies whose positions are both measured: the cube of their
        # difference (plugins/_bodies.py), each pair alone and every pair together.
        pairs = _bodies.screened_pairs(ctx)
        for pair in pairs:
            for about, centre in pair.centres().items():
                term = _bodies.pair_term(pair, "pow", centre=centre, power=3)
                outs.append(({"structure": "between two outputs", "between": pair.label,
                              "powers": [3], "about": about}, [term]))  # fmt: skip
        if len(pairs) > 1:
            terms = [_bodies.pair_term(pair, "pow", power=3) for pair in pairs]
            between = [pair.label for pair in pairs]
            outs.append(({"structure": "between two outputs", "between": between,
                          "powers": [3], "about": "mean"}, terms))  # fmt: skip
        return outs

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the residual with the part of y^3 that is not linear in y."""
        out = {}
        for j, n in enumerate(valid.outputs):
            y = valid.y[:, j] - valid.y[:, j].mean()
            cube = y**3
            cube = cube - np.dot(cube, y) / max(np.dot(y, y), 1e-300) * y
            out[n] = _corr(res.residual[:, j], cube)
        large = {c.output: c.ratio for c in res.concentration if c.condition == "large |output|"}
        return {
            "statistic": "corr(residual, y^3 ⟂ y)",
            "value": out,
            "large_output_concentration": large,
            "signal": "cube of the output",
        }


def _without_offset(ctx: Context) -> float | None:
    """Training score of the baseline refitted without its constant (None if it has none).

    An ARX is refitted without its offset.  A refined N4SID fallback identified around an
    operating point (diagnose's check at the baseline's operating point) is identified again
    without it by its identifier (``without_operating_point``; a generic oscillator with a
    weight at 0.01 s: the constant load was in the fallback's operating point, so it removed
    nothing and the weight's angle dependence was never tried — a stiffness was named).
    """
    rep = ctx.baseline.representation
    bare_fallback = getattr(ctx.identifier, "without_operating_point", None)
    try:
        if isinstance(rep, ARX) and rep.offset is not None:
            bare = ctx.baseline.replace(representation=dataclasses.replace(rep, offset=None))
            return ctx.score(extend_with_terms(bare, ctx.train, []))
        if isinstance(rep, StateSpace) and rep.has_offsets and bare_fallback is not None:
            plain = bare_fallback(ctx.train)
            return None if plain is None else ctx.score(plain)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError, TendonkitError):
        return None
    return None


class Gravity(_TermEffect):
    """Gravity: a constant load that shifts the operating point, varying with the angle."""

    name = "gravity"
    cause = "gravity"
    #: Share of the training misfit a constant load must remove before its angle dependence
    #: (``sin``, ``cos``) is tried.
    load_share = 0.05
    description = (
        "Gravity: adds a constant load and, for angle outputs, cos(y) of every output (the "
        "angle-dependent part of a weight's torque)."
    )

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        const = [Term()]
        cands: list[tuple[dict[str, Any], list[Term]]] = [({"terms": "constant"}, const)]
        y = ctx.train.y
        if np.all(np.abs(y) < 2 * np.pi):  # plausible angles in radians
            # cos is even: it models the angle-dependent weight without mimicking the odd,
            # amplitude-dependent terms of a nonlinear stiffness (sin y = y - y^3/6 would).
            cos_terms = [Term((Factor(n, fn="cos", lag=1),)) for n in ctx.train.outputs]
            cands.append(({"terms": "constant+cos"}, const + cos_terms))
            # The whole torque of a weight on a link mounted at an angle θ0,
            # m g l sin(y + θ0) = a sin y + b cos y: its odd part overlaps a stiffness, so it
            # is only a candidate together with the even part and the constant.
            sin_terms = [Term((Factor(n, fn="sin", lag=1),)) for n in ctx.train.outputs]
            cands.append(({"terms": "constant+sin+cos"}, const + sin_terms + cos_terms))
        return cands

    def extend(self, ctx: Context) -> Extension | None:
        """A constant load first; its angle dependence only if the load itself is supported.

        ``sin`` and ``cos`` of an output together can imitate a general even-plus-odd stiffness
        (Silverbox, an electronic Duffing oscillator with no load, gains +12 points with them).
        What sets gravity apart is the load: the angle-dependent candidates are tried only when
        the constant alone improves the training simulation fit.
        """
        cands = self.builders(ctx)
        params, model, score, _ = ctx.select(cands[:1])
        # "Supported": the constant removes at least LOAD_SHARE of the training misfit
        # (100 - fit).  Loads measured: 12-42 % (robot on a horizontal mount, a pendulum);
        # no load: < 1 % (robot, Duffing systems, linear systems).
        misfit = 100.0 - ctx.baseline_score
        supported = model is not None and 100.0 - score <= (1.0 - self.load_share) * misfit
        without = _without_offset(ctx) if len(cands) > 1 else None
        if without is not None:
            # The baseline has an operating point already (diagnose's automatic baseline
            # chooses one): the load is judged by what that constant does, the same share of
            # the misfit the baseline would have without it.
            supported = 100.0 - ctx.baseline_score <= (1.0 - self.load_share) * (100.0 - without)
        if not supported or len(cands) == 1:
            return ctx.extension(params, model, score, self.description)
        p_angle, m_angle, s_angle, tried = ctx.select(cands[1:])
        if without is not None and not self._even_part_supported(ctx, tried):
            # With the operating point in the baseline, the constant says nothing, and the
            # odd part of a weight's torque (sin y) is what a stiffness adds too: gravity is
            # told by the even part (cos y), which must remove its share of the misfit that
            # the odd part leaves (Silverbox, a Duffing circuit whose input has a mean, gained
            # +11.25 with sin+cos against the stiffness's +11.21, with no even part at all).
            return ctx.extension(params, model, score, self.description)
        if m_angle is not None and s_angle > score:
            params, model, score = p_angle, m_angle, s_angle
        return ctx.extension(params, model, score, self.description)

    def _even_part_supported(self, ctx: Context, tried: list[dict[str, Any]]) -> bool:
        """Does ``cos y`` remove ``load_share`` of the misfit that ``sin y`` leaves?

        ``tried`` is :meth:`Context.select`'s record of the angle-dependent candidates.
        """
        full = [
            t
            for t in tried
            if t["score"] is not None and any("sin(" in x for x in t["params"].get("terms", []))
        ]
        if not full:
            return True
        odd = [Term((Factor(n, fn="sin", lag=1),)) for n in ctx.train.outputs] + [Term()]
        _, _, s_odd, _ = ctx.select([({}, lambda d: extend_with_terms(ctx.baseline, d, odd))])
        return bool(100.0 - full[0]["score"] <= (1.0 - self.load_share) * (100.0 - s_odd))

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Mean of the residual relative to its spread (a static offset)."""
        r = res.residual
        return {
            "statistic": "mean(residual) / std(residual)",
            "value": {
                n: float(r[:, j].mean() / (r[:, j].std() + 1e-300))
                for j, n in enumerate(valid.outputs)
            },
            "signal": "operating point (mean output)",
        }


class StaticNonlinearity(_TermEffect):
    """A memoryless nonlinearity on a signal path: Hammerstein, Wiener, Wiener–Hammerstein."""

    name = "static_nonlinearity"
    cause = "static_nonlinearity"
    description = (
        "Static nonlinearity: a memoryless curve on the input path (Hammerstein: u^2, u^3 or |u| "
        "at every input lag the model reads), after the dynamics (Wiener: a polynomial output "
        "block, a sensor curve such as a rectifier), or between two filters "
        "(Wiener-Hammerstein)."
    )

    #: Degrees of the curve between the two filters (each as powers at every input lag).
    between_degrees = (3, 5, 7, 9)
    #: Training samples per parameter below which a degree is not tried.
    samples_per_parameter = 100
    #: Share of a curve-between-two-filters candidate's training gain that its curve must earn
    #: over the same structure without the curve (:meth:`extend`).
    between_earns = 0.5

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        base = ctx.baseline
        u = ctx.train.u
        mu_u, sd_u = u.mean(axis=0), np.where(u.std(axis=0) > 0, u.std(axis=0), 1.0)

        in_lags = [_bodies.input_lags(base, m) for m in range(len(ctx.train.inputs))]
        hammer = [
            Term((Factor(name, power=p, lag=lag, scale=float(1 / sd_u[j]), offset=float(mu_u[j])),))
            for p in (2, 3)
            for j, name in enumerate(ctx.train.inputs)
            for lag in in_lags[j]
        ]
        absu = [
            Term((Factor(name, fn="abs", lag=lag, scale=float(1 / sd_u[j])),))
            for j, name in enumerate(ctx.train.inputs)
            for lag in in_lags[j]
        ]
        # No powers of past outputs: inside the recursion they are nonlinear *dynamics* (a
        # tank's outflow sqrt(h), a time constant that moves with the level), not a curve on a
        # signal path.  A curve after the dynamics is the Wiener candidate's output block, one
        # between two filters the Wiener-Hammerstein candidates' (builders).
        return [
            ({"structure": "Hammerstein", "curve": "cubic polynomial"}, hammer),
            ({"structure": "Hammerstein", "curve": "|u|"}, absu),
        ]

    def builders(self, ctx: Context) -> Candidates:
        """The term candidates, and a Wiener structure: a cubic curve after the model.

        The terms put the curve on past inputs inside the recursion (Hammerstein).  A curve
        *after* the dynamics — a rectifying speed sensor, a diode at the output — is not a
        function of past outputs, whose values it has already bent: it acts on the model's
        inner signal, which is not measured.  The Wiener candidate is the baseline structure
        with a ``polynomial`` output block, fitted by alternating least squares
        (:func:`tendonkit.diagnose.fit_wiener`), its ARX order chosen again with the curve in
        place where the baseline chose its own (:func:`_wiener_order`); a named one is refined
        by simulation error, all of it, like every extension.
        """
        cands, between, _ = self._all_builders(ctx)
        return cands + between

    def extend(self, ctx: Context) -> Extension | None:
        """The best candidate — where it is a curve between two filters, only if the curve
        earns :attr:`between_earns` of its training gain over its own linear part.

        The first filter is made of the baseline's own poles and zeros, so the structure
        without its curve (the filter, then the baseline's structure identified again on the
        filtered input) is a *linear* model of more memory than the baseline.  On a linear
        plant whose output noise is slow (AR 0.995: ``benchmarks/bench_diagnose_null.py``) that
        linear part alone predicted the validation data one step ahead 18 % better than the
        ARX baseline (p = 7e-20), the curve added nothing (p = 1), and the curve was named
        (+0.7 … +3.1 points) on 4 of 200 such plants.  Where the filters earn the gain (or the
        linear part cannot be fitted), the other candidates are chosen from (the refusal is in
        the chosen one's ``between_refused``); where the curve earns it, the linear part is the
        extension's
        :attr:`~tendonkit.diagnose.Extension.linear_part`, which the validation test must
        beat too.
        """
        cands, between, linear = self._all_builders(ctx)
        other = _bodies.best_extension(ctx, cands, self.description)
        ext = _bodies.best_extension(ctx, between, self.description) if between else None
        if (
            ext is None
            or linear is None
            or (other is not None and ext.train_gain <= other.train_gain)
        ):
            return other
        try:
            linear_model: Model | None = linear(ctx.train)
            linear_score = ctx.score(linear_model)  # type: ignore[arg-type]
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError):
            linear_model, linear_score = None, math.inf  # not verifiable: the curve is refused
        curve_gain = ctx.baseline_score + ext.train_gain - linear_score
        if linear_model is not None and curve_gain >= self.between_earns * ext.train_gain:
            return dataclasses.replace(ext, linear_part=linear_model)
        if other is None:
            return None
        refused = {
            "curve": ext.params["curve"],
            "train_gain": ext.train_gain,
            "curve_train_gain": curve_gain if math.isfinite(curve_gain) else None,
        }
        return dataclasses.replace(other, params={**other.params, "between_refused": refused})

    def _all_builders(self, ctx: Context) -> tuple[Candidates, Candidates, Builder | None]:
        """The candidates of :meth:`builders`: the others, the curves between two filters,
        and the builder of those curves' linear part (None where there are none)."""
        cands = super().builders(ctx)
        if ctx.baseline.output_blocks:
            return cands, [], None
        params: dict[str, Any] = {"structure": "Wiener", "curve": "cubic output polynomial"}
        refit = ctx.refit
        order = _wiener_order(ctx)
        if order is not None:
            n, inner_refit, table = order
            params = {**params, "inner_order": n, "orders_tried": table}
            refit = inner_refit
        cands.append((params, lambda d: fit_wiener(refit, d)))
        between, linear = self._filtered_curves(ctx)
        return cands, between, linear

    def _filtered_curves(self, ctx: Context) -> tuple[Candidates, Builder | None]:
        """Wiener–Hammerstein: a curve *between* two filters, the first one from the data;
        and the builder of the same structure without the curve (None with no candidate).

        The Hammerstein terms put the curve on the raw input; in a Wiener–Hammerstein system
        it acts on the input after a first filter.  That filter is taken from the baseline's
        own dynamics: the split of its poles and zeros that best explains the training data
        (:func:`tendonkit.plugins._bla_split.best_split`), written as ``second_order_section``
        input blocks; the baseline's structure is identified again on the filtered input,
        with the curve as powers 2…d of it at every input lag the model reads.  Refined as a
        named extension is, the filter's coefficients move with the rest.  SISO ARX baselines
        only; degrees whose parameters would have fewer than ``samples_per_parameter``
        training samples each are not tried.
        """
        split = best_split(ctx.baseline, ctx.train)
        if split is None:
            return [], None
        blocks, record = split
        base = ctx.baseline
        name = base.input_names[0]
        inner = transform_inputs(ctx.train, blocks).u[:, 0]
        mu, sd = float(inner.mean()), float(inner.std()) or 1.0
        lags = _bodies.input_lags(base, 0)
        n = sum(e.n_samples for e in ctx.train.experiments)
        n_linear = free_parameters(base, blocks=False)
        linear = refit_with_input_blocks(ctx.refit, blocks)
        out: Candidates = []
        for degree in self.between_degrees:
            terms = [
                Term((Factor(name, power=p, lag=lag, scale=1.0 / sd, offset=mu),))
                for p in range(2, degree + 1)
                for lag in lags
            ]
            n_params = len(terms) + 4 * len(blocks) + n_linear
            if n < self.samples_per_parameter * n_params:
                break

            def build(d: Dataset, terms: list[Term] = terms) -> Model:
                return extend_with_terms(linear(d), d, terms)

            params = {
                "structure": "Wiener-Hammerstein",
                "curve": f"polynomial of degree {degree} between two filters",
                **record,
            }
            out.append((params, build))
        return out, (linear if out else None)

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the residual with the square of the input (even part of a curve)."""
        out = {}
        for j, n in enumerate(valid.outputs):
            best = 0.0
            for m in range(valid.u.shape[1]):
                x = valid.u[:, m] - valid.u[:, m].mean()
                sq = x**2 - np.mean(x**2)
                c = _corr(res.residual[:, j], sq)
                best = c if abs(c) > abs(best) else best
            out[n] = best
        return {
            "statistic": "max corr(residual, u^2)",
            "value": out,
            "signal": "square of the input",
        }


def _wiener_order(
    ctx: Context,
) -> tuple[int, Callable[[Dataset], Model], list[dict[str, Any]]] | None:
    """The Wiener candidate's ARX order ``na = nb``, chosen with the curve in place.

    Only where the baseline chose its own orders (``ctx.max_order``: the automatic ARX) —
    by the blocked cross-validation of the simulation error on the training data; the same
    choice is made again here for the Wiener structure (:func:`fit_wiener` on each fold's
    fitting part, scored on its held-out block after the initialisation window), because an
    order chosen for a *linear* model of a bent output is not the order of the dynamics before
    the bend: on the coupled drives the linear choice is ARX(1, 1) and the Wiener model's
    ARX(1, 1) simulates the low-amplitude record worse than the linear baseline.  The smallest
    order within 1 % of the best held-out error wins, as for the baseline.  None where the
    baseline's orders stand (given by the user, or not an ARX).
    """
    ident = ctx.identifier
    if ctx.max_order < 1 or not isinstance(ident, ArxOptions) or not isinstance(ident.na, int):
        return None
    nu = ctx.train.nu
    window = cv_window(ctx.max_order, _as_tuple(ident.nk, nu))
    try:
        folds = cv_folds(ctx.train, window)
    except TendonkitError:
        return None

    def refit_of(n: int) -> Callable[[Dataset], Model]:
        trial = dataclasses.replace(ident, na=n, nb=(n,) * nu)

        def refit(data: Dataset) -> Model:
            with without_training_fit():
                return trial.identify(data)  # type: ignore[no-any-return]

        return refit

    table = []
    for n in range(1, ctx.max_order + 1):
        err = held_out_or_inf(lambda d, n=n: fit_wiener(refit_of(n), d), folds, window)
        if np.isfinite(err):
            table.append({"order": n, "held_out_rms": err})
    if not table:
        return None
    top = min(r["held_out_rms"] for r in table)
    best = int(min(r["order"] for r in table if r["held_out_rms"] <= top * (1.0 + ARX_PARSIMONY)))
    return best, refit_of(best), table


def _stop(y: np.ndarray, width: float) -> np.ndarray:
    """The stop operator ``y - play(y)``: a force that grows with the displacement since the
    last reversal and levels off at ``±width`` (elastic-perfectly-plastic)."""
    return y - Factor("y", fn="play", param=width).value(y)


class Hysteresis(_TermEffect):
    """Hysteresis inside the dynamics: a restoring force that depends on the path, not only on
    the present position and velocity (Bouc-Wen, Prandtl-Ishlinskii)."""

    name = "hysteresis"
    cause = "hysteresis"
    description = (
        "Hysteresis: adds a hysteresis operator of every output — a Bouc-Wen state "
        "dh = dy - a|dy|h - b·dy|h| (a smooth loop, softening or hardening), a play of "
        "half-width w (elastic-perfectly-plastic) or plays of three widths with their own "
        "weights (Prandtl-Ishlinskii) — whose memory the simulation carries; or a Bouc-Wen "
        "state or a play of the difference of two outputs (a hysteretic coupling between two "
        "bodies)."
    )
    #: Bouc-Wen shapes ``a`` per unit of the output's standard deviation (``a = 1``: the
    #: loop's yield is reached after about one standard deviation of travel) and ``b / a``
    #: (negative: the loop hardens on loading, as in the Bouc-Wen benchmark; 0.5: softens).
    bouc_wen_a = (0.25, 0.5, 1.0, 2.0)
    bouc_wen_ratio = (-1.5, -0.5, 0.5)
    #: Half-widths of a play, as fractions of the output's standard deviation (the
    #: Prandtl-Ishlinskii candidate's).  A play alone is tried at the wider ones only: a
    #: narrower one holds the direction of motion at rest, which is friction's
    #: (``CoulombFriction.direction_widths``): its elastic range is within the noise.
    play_fractions = (0.05, 0.15, 0.4)
    single_play_fractions = (0.15, 0.4)
    #: The Bouc-Wen shapes tried between two outputs.
    between_a = (0.5, 2.0)
    between_ratio = (-0.5, 0.5)

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        y = ctx.train.y
        mu = y.mean(axis=0)
        sd = np.where(y.std(axis=0) > 0, y.std(axis=0), 1.0)

        def operator(fn: str, param: float, param2: float = 0.0) -> list[Term]:
            """The operator on every output's past sample, normalised by its mean and std."""
            return [
                Term((Factor(n, fn=fn, lag=1, scale=float(1 / sd[j]), offset=float(mu[j]),
                             param=param, param2=param2),))
                for j, n in enumerate(ctx.train.outputs)
            ]  # fmt: skip

        outs: list[tuple[dict[str, Any], list[Term]]] = [
            ({"structure": "bouc_wen", "a": a, "b": a * r}, operator("bouc_wen", a, a * r))
            for a in self.bouc_wen_a
            for r in self.bouc_wen_ratio
        ]
        outs += [
            ({"structure": "play", "half_width_in_std": w}, operator("play", w))
            for w in self.single_play_fractions
        ]
        # Prandtl-Ishlinskii: the plays of every width together, each with its own weight (a
        # loop made of straight pieces, any mix of softening and hardening)
        pi = [t for w in self.play_fractions for t in operator("play", w)]
        widths = list(self.play_fractions)
        outs.append(({"structure": "prandtl_ishlinskii", "half_widths_in_std": widths}, pi))
        # A hysteretic coupling between two bodies whose positions are both outputs (a rubber
        # mount, a tendon's sheath, a bolted joint that slips): the operator on the difference
        # of the two outputs (plugins/_bodies.py); fewer Bouc-Wen shapes than above
        for pair in _bodies.screened_pairs(ctx):
            between = {"between": pair.label}
            outs += [
                ({"structure": "bouc_wen", **between, "a": a, "b": a * r},
                 [_bodies.pair_term(pair, "bouc_wen", param=a, param2=a * r)])
                for a in self.between_a
                for r in self.between_ratio
            ]  # fmt: skip
            outs += [
                ({"structure": "play", **between, "half_width_in_std": w},
                 [_bodies.pair_term(pair, "play", param=w)])
                for w in self.play_fractions
            ]  # fmt: skip
        return outs

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the residual with a stop operator of the output, its part along the
        direction of motion removed: a force that builds up with the travel since the last
        reversal (hysteresis), not one that jumps at the reversal (Coulomb friction)."""
        out = {}
        for j, n in enumerate(valid.outputs):
            y = valid.y[:, j] - valid.y[:, j].mean()
            sd = float(y.std()) or 1.0
            stop = _stop(y / sd, 0.3)
            direction = np.sign(_velocity(y, 1))
            both = np.column_stack([direction, y / sd, np.ones_like(y)])
            coef = np.linalg.lstsq(both, stop, rcond=None)[0]
            out[n] = _corr(res.residual[:, j], stop - both @ coef)
        return {
            "statistic": "corr(residual, stop operator ⟂ sign(velocity), y)",
            "value": out,
            "signal": "travel since the last reversal",
        }


@hookimpl
def tendonkit_register_effects(registry):  # type: ignore[no-untyped-def]
    """Register the term-based effects."""
    registry.add(CoulombFriction())
    registry.add(NonlinearStiffness())
    registry.add(Gravity())
    registry.add(StaticNonlinearity())
    registry.add(Hysteresis())
