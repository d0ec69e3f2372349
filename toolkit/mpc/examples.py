"""Small known systems shaped like the tendon robot, for MPC tests, docs and benchmarks.

- :func:`two_mode_model`: linear pan/tilt modes (3.6 Hz and 4.7 Hz) driven by the
  antagonistic tendon pairs (T1, T3) and (T2, T4), sampled at 30 ms; at equal tensions the
  joints are straight, and a tension difference of about 85 N bends a joint by 0.5 rad.
- :func:`tendon_sparse_map`: a two-state SINDYc-like map with state-dependent tendon moment
  arms (``u·cos(q)``) and stiffening by the orthogonal pair (``u·sin(q)``).
"""

from __future__ import annotations

import numpy as np

from ..schema import Model, Provenance, Signal, SparseMap, StateSpace
from ..terms import Factor, Term
from ..testsystems import random_state_space

TENDONS = tuple(Signal(f"F{i}", "N") for i in range(1, 5))


def two_mode_model(
    *,
    gain: float = 0.006,
    freqs: tuple[float, float] = (3.6, 4.7),
    damping: float = 0.5,
    coupling: float = 0.05,
    dt: float = 0.03,
    name: str = "two-mode tendon robot",
) -> Model:
    """Linear pan/tilt model: ``q̈ + 2ζω q̇ + ω² q = ω² gain (F_a - F_b)`` per joint, ZOH sampled.

    Parameters
    ----------
    gain : float
        Static gain in rad per newton of tension difference.
    freqs : (float, float)
        Natural frequencies of the pan and tilt modes (Hz).
    damping : float
        Damping ratio of both modes.
    coupling : float
        Fraction of each pair's tension difference that also drives the other joint.
    dt : float
        Sample time (s).
    name : str
        Model name.
    """
    # lazy: heavy (scipy)
    from scipy.signal import cont2discrete

    Ac = np.zeros((4, 4))
    Bc = np.zeros((4, 4))
    diff = np.array([[1.0, coupling, -1.0, -coupling], [coupling, 1.0, -coupling, -1.0]])
    for i, f in enumerate(freqs):
        w = 2 * np.pi * f
        Ac[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = [[0.0, 1.0], [-(w**2), -2 * damping * w]]
        Bc[2 * i + 1] = w**2 * gain * diff[i]
    C = np.zeros((2, 4))
    C[0, 0] = C[1, 2] = 1.0
    A, B, *_ = cont2discrete((Ac, Bc, C, np.zeros((2, 4))), dt, method="zoh")
    return Model(
        name=name,
        dt=dt,
        inputs=TENDONS,
        outputs=(Signal("q1", "rad"), Signal("q2", "rad")),
        representation=StateSpace(A=A, B=B, C=C, D=np.zeros((2, 4))),
        provenance=Provenance(identifier="truth", notes="tendonkit.mpc.examples.two_mode_model"),
    )


def tendon_sparse_map(
    *,
    pole: float = 0.9,
    arm: float = 0.0015,
    stiffening: float = 0.0004,
    bend: float = 1.0,
    dt: float = 0.03,
) -> Model:
    """Nonlinear two-joint map ``q+ = pole q + arm (F_a - F_b) cos q - stiffening (F_c + F_d) sin q``.

    Pan ``q1`` is driven by (F1, F3) and stiffened by (F2, F4); tilt ``q2`` the other way
    round; the moment arm shrinks as ``cos(bend·q)``.  States and outputs are ``q1, q2``.

    Parameters
    ----------
    pole : float
        Coefficient of ``q`` itself.
    arm : float
        Moment-arm coefficient of the tension difference (rad/N per step).
    stiffening : float
        Coefficient of the orthogonal pair's ``u·sin(q)`` restoring term.
    bend : float
        How fast the moment arm shrinks with the angle.
    dt : float
        Sample time (s).
    """
    terms: list[Term] = []
    coef: list[list[float]] = []
    pairs = {"q1": ("F1", "F3", "F2", "F4"), "q2": ("F2", "F4", "F1", "F3")}
    for j, (q, (a, b, c, d)) in enumerate(pairs.items()):
        row = [0.0, 0.0]
        for term, value in (
            (Term((Factor(q),)), pole),
            (Term((Factor(a), Factor(q, fn="cos", scale=bend))), arm),
            (Term((Factor(b), Factor(q, fn="cos", scale=bend))), -arm),
            (Term((Factor(c), Factor(q, fn="sin"))), -stiffening),
            (Term((Factor(d), Factor(q, fn="sin"))), -stiffening),
        ):
            terms.append(term)
            r = list(row)
            r[j] = value
            coef.append(r)
    return Model(
        name="tendon sparse map",
        dt=dt,
        inputs=TENDONS,
        outputs=(Signal("q1", "rad"), Signal("q2", "rad")),
        states=(Signal("q1", "rad"), Signal("q2", "rad")),
        representation=SparseMap(
            terms=tuple(terms), coefficients=np.array(coef), output_states=(0, 1)
        ),
        provenance=Provenance(identifier="truth", notes="tendonkit.mpc.examples.tendon_sparse_map"),
    )


def random_tendon_model(n_states: int = 8, *, seed: int = 0, gain: float = 0.006) -> Model:
    """A random stable system driven by the two antagonistic tension differences.

    ``tendonkit.testsystems.random_state_space(n_states, 2, 2)`` with its two inputs fed by
    ``F1 - F3`` and ``F2 - F4`` and scaled so that the larger static gain is ``gain`` rad/N
    (about ±0.5 rad for 20..190 N); equal tensions give zero outputs.

    Parameters
    ----------
    n_states : int
        Even order.
    seed : int
        Seed of :func:`~tendonkit.testsystems.random_state_space`.
    gain : float
        Largest absolute static gain (rad/N).
    """

    base = random_state_space(n_states, 2, 2, seed=seed, dt=0.03).representation
    assert isinstance(base, StateSpace)
    G0 = base.C @ np.linalg.solve(np.eye(n_states) - base.A, base.B)
    M = np.array([[1.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, -1.0]])
    B = base.B @ M * (gain / np.max(np.abs(G0)))
    return Model(
        name=f"random tendon system n={n_states} (seed {seed})",
        dt=0.03,
        inputs=TENDONS,
        outputs=(Signal("q1", "rad"), Signal("q2", "rad")),
        representation=StateSpace(A=base.A, B=B, C=base.C, D=np.zeros((2, 4))),
        provenance=Provenance(
            identifier="truth", notes="tendonkit.mpc.examples.random_tendon_model"
        ),
    )
