"""tendonkit's pytest plugin: co-simulation tests of a controller, written like any other test.

Installed with tendonkit (entry point ``pytest11``), so a controller team's test files get these
fixtures without a ``conftest.py`` (docs/pytest-plugin.md has a complete example file):

``cosim``
    ``cosim(controller, *, plant=None, effects=(), preset="nominal", reference="petal",
    duration=None, seed=0)`` co-simulates one run on the plant FMU and returns a
    :class:`CosimCheck`: its ``metrics`` (those of a campaign row) and ``check(**criteria)``,
    which fails the test with every unmet criterion, the metric values and the plant.
    ``controller`` is a model (the linear or nonlinear MPC is built for it with the tuned
    settings), a model file, a controller object (``reset``/``step``), or None (open loop).
``plant_fmu``
    The plant FMU of a preset, built once and cached (``plant_fmu()`` or ``plant_fmu("paper_like")``).
``campaign``
    ``campaign(spec, *, jobs=1, scheduler=None)`` runs a campaign (a TOML path or the same
    structure as a dict) in the test's temporary folder and returns its
    :class:`~tendonkit.robot.campaign.CampaignResult`; ``result.check()`` asserts the pass rate.

:func:`draws` gives plant draws for ``pytest.mark.parametrize`` (seeded, from the same ranges a
campaign takes), so one test runs on several plants and each draw is its own test id.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from ..errors import OptionError
from ..schema import Model
from .campaign import (
    METRICS,
    CampaignResult,
    Criterion,
    ReferenceSpec,
    metrics_of,
    plant_items,
    run_campaign,
    spec_from_dict,
)
from .collect import fmu_parameters
from .controllers import make_controller
from .cosim import CosimResult, run

__all__ = ["CosimCheck", "draws"]


def draws(vary: Mapping[str, Any], n: int, seed: int = 0, sampling: str = "random") -> list[Any]:
    """Plant draws for ``pytest.mark.parametrize("plant", draws(...))``.

    Parameters
    ----------
    vary : mapping
        As ``[plant.vary]`` of a campaign: ``name -> "spec"`` (the plant spec's range),
        ``{"range": [low, high]}`` (``"log": True`` for log-uniform) or a list of values.
    n : int
        Draws (random sampling); a grid has every combination.
    seed : int
        The draws depend on the seed and their number only.

    Returns
    -------
    list of pytest.param
        Each a dict of plant parameters, with a readable id.
    """
    table = {k: ({"values": v} if isinstance(v, list) else v) for k, v in vary.items()}
    camp: dict[str, Any] = {"seed": seed, "sampling": sampling}
    if sampling == "random":
        camp["draws"] = n
    spec = spec_from_dict(
        {"campaign": camp, "plant": {"vary": table}, "controllers": [{"kind": "open_loop"}]},
        source="draws()",
    )
    out = []
    for d in range(spec.n_draws):
        params = spec.draw(d)
        ident = ",".join(
            f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in params.items()
        )
        out.append(pytest.param(params, id=ident or f"draw{d}"))
    return out


@dataclass
class CosimCheck:
    """One co-simulation in a test: the result, its metrics, and assertions on them."""

    result: CosimResult
    metrics: dict[str, float]
    plant: dict[str, Any]

    def check(self, **criteria: float | str) -> None:
        """Fail the test unless every criterion holds.

        ``metric=value`` means ``metric <= value``; ``metric="OP value"`` takes any of
        ``<= < >= > == !=``.  Metrics: :data:`tendonkit.robot.campaign.METRICS`.
        """
        failed, problems = [], []
        for name, want in criteria.items():
            if name not in METRICS:
                problems.append(f"unknown metric {name!r}; metrics: {', '.join(METRICS)}")
                continue
            try:
                text = f"{name} {want}" if isinstance(want, str) else f"{name} <= {float(want)!r}"
                c = Criterion.parse(text)
            except (TypeError, ValueError):
                problems.append(f"{name}={want!r} is not a number or 'OP NUMBER'")
                continue
            if not c.holds(self.metrics):
                failed.append(f"{c} (got {self.metrics[name]:.4g})")
        if problems:
            raise OptionError("Invalid criteria:", problems)
        if failed:
            plant = ", ".join(f"{k}={v}" for k, v in self.plant.items()) or "nominal"
            pytest.fail(
                f"{self.result.controller} on the plant ({plant}): " + "; ".join(failed),
                pytrace=False,
            )


def _controller(controller: Any) -> Any:
    if controller is None:
        return None
    if isinstance(controller, str | Path):
        controller = Model.load(controller)
    if isinstance(controller, Model):
        return make_controller(controller)
    return controller


@pytest.fixture(scope="session")
def plant_fmu() -> Callable[[str], Path]:
    """``plant_fmu(preset="nominal")``: the plant FMU of a preset (built once, cached)."""
    # lazy: tendonkit.fmu builds the plant (pythonfmu) only when a test asks for it
    from tendonkit.fmu.build import cached_plant_fmu, plant_parameters

    cache: dict[str, Path] = {}

    def get(preset: str = "nominal") -> Path:
        if preset not in cache:
            cache[preset] = cached_plant_fmu(plant_parameters([], preset))
        return cache[preset]

    return get


@pytest.fixture
def cosim(plant_fmu: Callable[[str], Path]) -> Callable[..., CosimCheck]:
    """``cosim(controller, *, plant=None, effects=(), preset="nominal", reference="petal",
    duration=None, seed=0, speed=2.5, amplitude=9.0)`` -> :class:`CosimCheck`."""
    # lazy: tendonkit.fmu resolves the plant's effects
    from tendonkit.fmu.build import plant_parameters

    def go(
        controller: Any,
        *,
        plant: Mapping[str, Any] | None = None,
        effects: Sequence[str] = (),
        preset: str = "nominal",
        reference: str = "petal",
        duration: float | None = None,
        seed: int = 0,
        speed: float = 2.5,
        amplitude: float = 9.0,
        name: str | None = None,
    ) -> CosimCheck:
        fmu = plant_fmu(preset)
        # the same plant a campaign row with these effects and this draw describes
        items = plant_items(list(effects), dict(plant or {}))
        full = plant_parameters([*items, f"seed={seed}"], preset)
        start = fmu_parameters(fmu)
        overrides = {k: v for k, v in full.items() if start.get(k) != v}
        ref = ReferenceSpec(reference, duration, speed, amplitude).build()
        ctrl = _controller(controller)
        label = name or (type(ctrl).__name__ if ctrl is not None else "open loop")
        res = run(fmu, ref, ctrl, parameters=overrides, name=label)
        shown: dict[str, Any] = dict(plant or {})
        if effects:
            shown["effects"] = list(effects)
        return CosimCheck(res, metrics_of(res), shown)

    return go


@pytest.fixture
def campaign(tmp_path: Path) -> Callable[..., CampaignResult]:
    """``campaign(spec, *, jobs=1, scheduler=None, base_dir=None)``: run a campaign here."""
    count = [0]

    def go(
        spec: Mapping[str, Any] | str | Path,
        *,
        jobs: int = 1,
        scheduler: str | None = None,
        base_dir: str | Path | None = None,
        report: bool = False,
    ) -> CampaignResult:
        count[0] += 1
        parsed = (
            spec_from_dict(dict(spec), base_dir=base_dir or Path.cwd(), source="campaign()")
            if isinstance(spec, Mapping)
            else spec
        )
        return run_campaign(
            parsed, tmp_path / f"campaign-{count[0]}", jobs=jobs, scheduler=scheduler, report=report
        )

    return go
