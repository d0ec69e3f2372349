"""Random models of every kind of the schema, for the equality tests across implementations.

ARX with linear, bilinear (``u·y``) and general terms, state space with terms, sparse maps;
random input and output blocks (delay, including fractional, dead zone, saturation, play,
first-order lag, rate limit) and every factor function, lag, difference and relative factor.  Used by the
compiled kernel's tests (tests/core/test_kernel.py) and the C FMU's (tests/fmu/test_c_fmu.py).
"""

from __future__ import annotations

import numpy as np

from tendonkit.schema import ARX, Block, Model, Signal, SparseMap, StateSpace
from tendonkit.terms import FUNCTIONS, Factor, Term

KINDS = ("arx_linear", "arx_terms", "arx_bilinear", "ss_terms", "sparse_map")


def _factor(rng: np.random.Generator, names: list[str], min_lag: dict[str, int]) -> Factor:
    name = str(rng.choice(names))
    fn = str(rng.choice(list(FUNCTIONS)))
    # one factor in four relative to a second signal (between two bodies)
    others = [n for n in names if n != name]
    minus = str(rng.choice(others)) if others and rng.random() < 0.25 else ""
    low = max(min_lag.get(name, 0), min_lag.get(minus, 0))
    return Factor(
        name,
        fn=fn,
        minus=minus,
        power=int(rng.integers(1, 4)),
        lag=int(rng.integers(low, 4)),
        diff=int(rng.choice([0, 0, 1, 2])),
        scale=float(rng.uniform(0.5, 2.0)),
        offset=float(rng.normal(0.0, 0.2)),
        param=float(rng.uniform(0.01, 0.5)),
        # a Bouc-Wen operator's second shape, a slew lag's largest step (the others ignore it)
        param2=(
            float(rng.uniform(-0.5, 0.5))
            if fn == "bouc_wen"
            else (float(rng.uniform(0.05, 0.5)) if fn == "slew_lag" else 0.0)
        ),
        # the second signal's weight: a loop closed through it (an actuator on a compliant load)
        weight=float(rng.choice([1.0, rng.uniform(0.5, 1.5)])) if minus else 1.0,
    )


def _terms(rng, names, min_lag, n) -> tuple[Term, ...]:
    return tuple(
        Term(tuple(_factor(rng, names, min_lag) for _ in range(int(rng.integers(0, 3)))))
        for _ in range(n)
    )


def _section(rng) -> dict[str, float]:
    """A stable section: a complex pole pair of radius < 0.9, any zeros nearby."""
    r, phi = rng.uniform(0.1, 0.9), rng.uniform(0, np.pi)
    return {
        "b1": float(rng.uniform(-1.5, 1.5)),
        "b2": float(rng.uniform(-0.8, 0.8)),
        "a1": float(-2 * r * np.cos(phi)),
        "a2": float(r * r),
    }


def _blocks(rng, names: list[str]) -> tuple[Block, ...]:
    out = []
    for name in names:
        kind = str(
            rng.choice(
                [
                    "none",
                    "delay",
                    "dead_zone",
                    "saturation",
                    "play",
                    "first_order_lag",
                    "rate_limit",
                    "polynomial",
                    "second_order_section",
                ]
            )
        )
        params = {
            "delay": {"samples": float(rng.choice([2.0, rng.uniform(0, 3)]))},
            "dead_zone": {"threshold": float(rng.uniform(0, 0.3)), "center": 0.1},
            "saturation": {"lower": -0.6, "upper": float(rng.uniform(0.2, 0.8))},
            "play": {"width": float(rng.uniform(0.01, 0.3))},
            "first_order_lag": {"pole": float(rng.uniform(0, 0.9))},
            "rate_limit": {"rate": float(rng.uniform(0.01, 0.3))},
            "polynomial": {
                "c0": 0.1,
                "c1": float(rng.uniform(0.5, 1.5)),
                "c2": float(rng.uniform(-0.3, 0.3)),
                "c3": float(rng.uniform(-0.1, 0.1)),
            },
            "second_order_section": _section(rng),
        }.get(kind)
        if params is not None:
            out.append(Block(kind, name, params))
    return tuple(out)


def random_model(seed: int, kind: str, gain: float) -> Model:
    """A random model of ``kind``; ``gain`` > 1 makes divergence likely."""
    rng = np.random.default_rng(seed)
    nu, ny = int(rng.integers(1, 4)), int(rng.integers(1, 3))
    ins = [f"u{i + 1}" for i in range(nu)]
    outs = [f"y{i + 1}" for i in range(ny)]
    past = {n: 1 for n in outs}  # ARX terms read past outputs only
    states: tuple[Signal, ...] = ()
    if kind.startswith("arx"):
        na, nb = int(rng.integers(0, 4)), int(rng.integers(1, 4))
        A = tuple(rng.normal(0, 0.3 / (na or 1), (ny, ny)) * gain for _ in range(na))
        B = tuple(rng.normal(0, 0.5, (ny, nu)) for _ in range(nb))
        terms: tuple[Term, ...] = ()
        if kind == "arx_terms":
            terms = _terms(rng, ins + outs, past, int(rng.integers(1, 6)))
        elif kind == "arx_bilinear":
            terms = tuple(
                Term((Factor(str(rng.choice(ins))), Factor(str(rng.choice(outs)), lag=lag)))
                for lag in range(1, int(rng.integers(2, 5)))
            ) + _terms(rng, ins, {}, 2)
        coef = rng.normal(0, 0.1, (len(terms), ny)) * gain if terms else None
        rep: ARX | StateSpace | SparseMap = ARX(
            A,
            B,
            tuple(int(k) for k in rng.integers(0, 3, nu)),
            offset=rng.normal(0, 0.1, ny),
            terms=terms,
            term_coefficients=coef,
        )
    elif kind == "ss_terms":
        n = int(rng.integers(1, 5))
        A = rng.normal(0, 0.4 / np.sqrt(n), (n, n)) * gain
        terms = _terms(rng, ins + outs, {}, int(rng.integers(1, 5)))
        rep = StateSpace(
            A,
            rng.normal(0, 0.5, (n, nu)),
            rng.normal(0, 1.0, (ny, n)),
            rng.normal(0, 0.1, (ny, nu)),
            terms=terms,
            E=rng.normal(0, 0.1, (n, len(terms))) * gain,
        )
    else:
        nx = ny + int(rng.integers(0, 2))
        states = tuple(Signal(f"x{i + 1}") for i in range(nx))
        snames = [s.name for s in states]
        lin = tuple(Term((Factor(s),)) for s in snames)
        terms = (Term(()), *lin, *_terms(rng, snames + ins, {}, int(rng.integers(1, 6))))
        coef = rng.normal(0, 0.05, (len(terms), nx)) * gain
        coef[1 : 1 + nx] += np.diag(rng.uniform(0.3, 0.8, nx)) * gain
        rep = SparseMap(terms, coef, tuple(range(ny)), x0=rng.normal(0, 0.1, nx))
    return Model(
        f"random_{kind}",
        0.01,
        tuple(Signal(n) for n in ins),
        tuple(Signal(n) for n in outs),
        rep,
        states=states,
        input_blocks=_blocks(rng, ins),
        output_blocks=_blocks(rng, outs),
    )
