"""Helpers shared by identifier plugins: signals, provenance, training fit."""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import functools
from collections.abc import Iterator
from importlib import metadata
from typing import Any

import numpy as np

from .dataset import Dataset
from .errors import DataError
from .metrics import fit
from .schema import Model, Provenance, Representation, Signal
from .simulate import simulate_dataset

_SKIP_TRAINING_FIT: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "tendonkit_skip_training_fit", default=False
)


@contextlib.contextmanager
def without_training_fit() -> Iterator[None]:
    """Within this block, :func:`build_model` leaves ``training_fit`` empty.

    ``diagnose`` re-identifies many candidate models that are scored on other data anyway;
    skipping their training-fit simulation saves most of its time.
    """
    token = _SKIP_TRAINING_FIT.set(True)
    try:
        yield
    finally:
        _SKIP_TRAINING_FIT.reset(token)


def one_blas_thread() -> contextlib.AbstractContextManager[object]:
    """Run BLAS on one thread (threadpoolctl) for the duration of an identification.

    Identification problems are tall and narrow (tens of columns): a second BLAS thread gains
    little, and on a busy two-core machine waiting for it made identification 5–10 times slower
    (measured by the n4sid benchmark: 0.41 s with one thread, 2.1 s with two at 200 000 samples).
    """
    return _threadpools().limit(limits=1, user_api="blas")


@functools.cache
def _threadpools() -> Any:
    """threadpoolctl's view of the loaded BLAS libraries (scanning them costs ~1 ms: once)."""
    # lazy: heavy (threadpoolctl)
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def signals(names: tuple[str, ...], units: dict[str, str]) -> tuple[Signal, ...]:
    """Signals for names, with the dataset's units where known."""
    return tuple(Signal(n, units.get(n, "")) for n in names)


def options_dict(options: Any) -> dict[str, Any]:
    """The options object as JSON-compatible data (tuples become lists)."""
    out = {}
    for f in dataclasses.fields(options):
        v = getattr(options, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


@functools.cache
def _version(plugin_module: str) -> str:
    """The installed version of the package a plugin lives in (``importlib.metadata`` scans
    every distribution on the path: about a millisecond a call, once per identified model)."""
    top = plugin_module.split(".")[0]
    try:
        return metadata.version(top)
    except metadata.PackageNotFoundError:
        return "unknown"


def build_model(
    options: Any,
    dataset: Dataset,
    representation: Representation,
    *,
    states: tuple[Signal, ...] = (),
    notes: str = "",
    name: str | None = None,
    details: dict[str, Any] | None = None,
) -> Model:
    """Wrap a representation into a :class:`Model` with provenance and its training fit.

    The training fit is the free-run simulation fit (initial state estimated) on the
    training data, mean over experiments weighted by length, per output.
    """
    model = Model(
        name=name or f"{options.name} model",
        dt=dataset.dt,
        inputs=signals(dataset.inputs, dataset.units),
        outputs=signals(dataset.outputs, dataset.units),
        states=states,
        representation=representation,
        provenance=Provenance(
            identifier=options.name,
            version=_version(type(options).__module__),
            options=options_dict(options),
            dataset_hash=dataset.hash(),
            notes=notes,
            details={"operating_point": operating_point(dataset), **(details or {})},
        ),
    )
    if _SKIP_TRAINING_FIT.get():
        return model
    return model.replace(
        provenance=dataclasses.replace(model.provenance, training_fit=training_fit(model, dataset))
    )


def operating_point(dataset: Dataset) -> dict[str, float]:
    """Mean of every input over the training data: where the model was identified.

    Exported FMUs start their inputs there (a master that does not set an input at once
    meets the model at its operating point, not at zero).
    """
    if not dataset.experiments or not dataset.nu:
        return {}
    mean = np.mean(np.vstack([e.u for e in dataset.experiments]), axis=0)
    return {name: float(f"{v:.6g}") for name, v in zip(dataset.inputs, mean, strict=True)}


def training_fit(model: Model, dataset: Dataset) -> dict[str, float]:
    """Free-run fit per output over all experiments of ``dataset`` (initial state estimated)."""

    sims = simulate_dataset(model, dataset, initial="estimate")
    y = np.vstack([e.y for e in dataset.experiments])
    f = fit(y, np.vstack(sims))
    return {name: float(v) if np.isfinite(v) else -1e300 for name, v in zip(model.output_names, f)}


def poor_fit_warning(model: Model) -> str | None:
    """Why ``model`` is useless on its own training data, or None: an output whose free run
    fits it no better than its mean (fit <= 0 %) says the structure does not suit the data
    (a dead time longer than the model's delays, an integrator, orders too low)."""
    poor = {n: v for n, v in model.provenance.training_fit.items() if not v > 0.0}
    if not poor:
        return None
    fits = ", ".join(f"{n} {v:.1f} %" if v > -1e299 else f"{n} diverged" for n, v in poor.items())
    return (
        f"the {model.provenance.identifier} model's free run explains its own training data no "
        f"better than their mean ({fits}): its structure does not suit these data (a dead "
        "time longer than its delays, an integrator, orders too low); choose the structure on "
        "the data (arx: na, nb and nk 'auto'; n4sid or pem: order left unset)."
    )


def is_int(v: object) -> bool:
    """Whether ``v`` is an integer option value (Python or numpy; a bool is not)."""
    return isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)


def require_samples(dataset: Dataset, needed: int, why: str) -> None:
    """Raise :class:`DataError` if an experiment is shorter than ``needed`` samples."""
    short = [e for e in dataset.experiments if e.n_samples < needed]
    if short:
        raise DataError(
            f"Too few samples for {why}:",
            [
                f"experiment {e.name or '#'} has {e.n_samples} samples; {needed} are needed."
                for e in short
            ],
        )
