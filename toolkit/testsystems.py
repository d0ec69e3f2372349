"""Built-in test systems with known truth, for tests, benchmarks and the quick demo."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .dataset import Dataset
from .schema import Model, Provenance, Signal, StateSpace
from .simulate import ss_response

FloatArray = NDArray[np.float64]


def random_state_space(
    n_states: int = 8, n_inputs: int = 4, n_outputs: int = 2, *, seed: int = 0, dt: float = 0.03
) -> Model:
    """A stable, minimal, well-damped discrete system (complex pole pairs, radius 0.80–0.97).

    Parameters
    ----------
    n_states : int
        Even number of states (pole pairs).
    n_inputs, n_outputs : int
        Signal counts.
    seed : int
        Seed of every random choice.
    dt : float
        Sample time in seconds.
    """
    rng = np.random.default_rng(seed)
    blocks = []
    for _ in range(n_states // 2):
        r = rng.uniform(0.80, 0.97)
        th = rng.uniform(0.05, 1.2)
        blocks.append(r * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]))
    A = np.zeros((n_states, n_states))
    for i, b in enumerate(blocks):
        A[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = b
    if n_states % 2:
        A[-1, -1] = rng.uniform(0.8, 0.95)
    T = rng.normal(size=(n_states, n_states)) + 3 * np.eye(n_states)
    A = T @ A @ np.linalg.inv(T)
    B = rng.normal(size=(n_states, n_inputs))
    C = rng.normal(size=(n_outputs, n_states))
    D = np.zeros((n_outputs, n_inputs))
    return Model(
        name=f"random system n={n_states} (seed {seed})",
        dt=dt,
        inputs=tuple(Signal(f"u{i + 1}", "N") for i in range(n_inputs)),
        outputs=tuple(Signal(f"y{i + 1}", "rad") for i in range(n_outputs)),
        representation=StateSpace(A=A, B=B, C=C, D=D),
        provenance=Provenance(identifier="truth", notes="tendonkit.testsystems.random_state_space"),
    )


def simulate_truth(
    model: Model, n_samples: int, *, noise: float = 0.01, seed: int = 1
) -> tuple[Dataset, FloatArray]:
    """Excite a state-space model with white Gaussian inputs and add output noise.

    ``noise`` is the output-noise standard deviation relative to each noise-free output's
    standard deviation (0.01 = 1 %).  Returns the noisy dataset and the noise-free outputs.
    """
    rep = model.representation
    assert isinstance(rep, StateSpace)
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n_samples, len(model.inputs)))
    y0 = ss_response(rep.A, rep.B, rep.C, rep.D, u, np.zeros(rep.n_states))
    y = y0 + noise * y0.std(axis=0) * rng.normal(size=y0.shape)
    ds = Dataset.from_arrays(
        u, y, model.dt, model.input_names, model.output_names, name=f"test-{seed}"
    )
    return ds, y0


def lightly_damped_oscillator(
    n_samples: int, *, noise: float = 0.05, seed: int = 0
) -> tuple[Dataset, FloatArray]:
    """A 1 Hz mass-spring-damper (damping ratio ≈ 0.05) sampled at 100 Hz, noise on the output.

    ``ẍ = u − 0.6 ẋ − 40 x``, zero-order-held input (white noise through a 2 Hz 2nd-order
    Butterworth), ``y = x + e`` with ``e`` white, of standard deviation ``noise`` times that of
    ``x``.  An *output-error* system: equation-error (least-squares) ARX estimates of it are
    biased, which makes it the standard check for output-error estimation and for diagnose's
    baseline check.  Returns the dataset (``force`` → ``pos``) and the true discrete poles.
    """
    # lazy: heavy (scipy)
    from scipy.signal import butter, cont2discrete, lfilter

    rng = np.random.default_rng(seed)
    sys_c = (np.array([[0.0, 1.0], [-40.0, -0.6]]), np.array([[0.0], [1.0]]), np.eye(1, 2), 0.0)
    A, B, C, _, _ = cont2discrete(sys_c, 0.01)
    u = lfilter(*butter(2, 2.0, fs=100.0), rng.standard_normal(n_samples))
    x = ss_response(A, B, C, np.zeros((1, 1)), u[:, None], np.zeros(2))[:, 0]
    y = x + noise * x.std() * rng.standard_normal(n_samples)
    ds = Dataset.from_arrays(u, y, 0.01, ("force",), ("pos",), name=f"oscillator-{seed}")
    return ds, np.linalg.eigvals(A)
