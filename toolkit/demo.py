"""``tendonkit demo``: the main job, end to end, with a report."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def run_identification_demo(
    out: Path, *, quick: bool = False, progress: bool = True
) -> dict[str, Any]:
    """Identify N4SID, ARX and SINDYc on the built-in 4-in 2-out order-8 test system.

    Returns the :func:`tendonkit.compare.compare` result on validation data and writes the
    models and ``fit_table.json`` into ``out``.
    """
    from tqdm import tqdm

    from tendonkit.cli import write_json
    from tendonkit.compare import compare, render_compare
    from tendonkit.manager import identifiers
    from tendonkit.testsystems import random_state_space, simulate_truth

    out.mkdir(parents=True, exist_ok=True)
    truth = random_state_space(8, 4, 2, seed=0)
    n = 3000 if quick else 10000
    train, _ = simulate_truth(truth, n, noise=0.01, seed=1)
    valid, _ = simulate_truth(truth, n // 2, noise=0.01, seed=2)
    registry = identifiers()
    plan = [("n4sid", {"order": 8}), ("arx", {"na": 8, "nb": 8, "nk": 1}), ("sindyc", {})]
    models, names = [truth], ["truth"]
    for method, options in tqdm(plan, desc="identify", disable=not progress):
        model = registry.get(method).create(**options).identify(train)
        model.save(out / f"{method}.json")
        models.append(model)
        names.append(method)
    result = compare(models, valid, names=names)
    write_json(out / "fit_table.json", result)
    print("Validation fit on the built-in test system (4 inputs, 2 outputs, order 8, 1 % noise):")
    print(render_compare(result))
    return result
