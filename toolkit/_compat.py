"""Old module paths of tendonkit 0.1, kept importable for one release with a DeprecationWarning.

tendonkit 0.2 moved the flat modules into rooms (docs/concepts.md).  Model FMUs exported by 0.1
import ``tendonkit.kinematics`` at run time inside the importer, and users' scripts import the
old paths, so every old path still imports: :func:`install` puts a finder on ``sys.meta_path``
that answers for the old names (and only after the real finders found nothing) with a thin
module forwarding every attribute to the module's new home.  Classes and functions are the same
objects, so ``isinstance`` and pickling are unaffected.

This module is the one place in the generic core that names the robot room, the CLI room and
the plugins, as strings only; it goes with the shims in the next release.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType
from typing import Any

#: Old module path -> new module path (or paths, searched in order, where a module was split).
MOVED_MODULES: dict[str, str | tuple[str, ...]] = {
    "tendonkit.augment": "tendonkit.diagnose.extend",
    "tendonkit.cli_mpc": "tendonkit.cli.mpc",
    "tendonkit.cli_robot": "tendonkit.cli.robot",
    "tendonkit.collect": "tendonkit.robot.collect",
    "tendonkit.controllers": "tendonkit.robot.controllers",
    "tendonkit.cosim": "tendonkit.robot.cosim",
    "tendonkit.demo": "tendonkit.robot.study",
    "tendonkit.diagnose_report": "tendonkit.diagnose.report",
    "tendonkit.figures_model": "tendonkit.figures",
    "tendonkit.findings": "tendonkit.diagnose.findings",
    "tendonkit.kinematics": "tendonkit.robot.kinematics",
    "tendonkit.protocol": "tendonkit.robot.protocol",
    "tendonkit.reconstruct": "tendonkit.robot.reconstruct",
    "tendonkit.refine": "tendonkit.plugins._output_error",
    "tendonkit.residuals": "tendonkit.diagnose.residuals",
    "tendonkit.stats": ("tendonkit.diagnose.stats", "tendonkit.diagnose.clip"),
}

#: Names that left a module whose path now belongs to another module: (old module, name) -> new
#: module.  ``tendonkit.figures`` held the robot's figures; it now holds the generic ones.
MOVED_NAMES: dict[tuple[str, str], str] = {
    ("tendonkit.figures", name): "tendonkit.robot.figures"
    for name in ("ee_path_figure", "fig2", "joint_angle_figure", "plot_tracking")
}


#: Attributes that left a class: (class name, attribute) -> (module, function of the instance).
MOVED_ATTRIBUTES: dict[tuple[str, str], tuple[str, str]] = {
    ("RobotParameters", "M0"): ("tendonkit.robot.kinematics", "rest_inertia"),
}


def _warn(old: str, new: str) -> None:
    warnings.warn(
        f"{old} moved to {new} in tendonkit 0.2; the old path works until the next release.",
        DeprecationWarning,
        stacklevel=3,
    )


def moved_name(module: str, name: str) -> Any:
    """Module ``__getattr__`` helper: a name that moved out of ``module``, with a warning."""
    new = MOVED_NAMES.get((module, name))
    if new is None:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    _warn(f"{module}.{name}", f"{new}.{name}")
    return getattr(importlib.import_module(new), name)


def moved_attribute(obj: Any, name: str) -> Any:
    """Instance ``__getattr__`` helper: an attribute that became a function, with a warning."""
    cls = type(obj).__name__
    new = MOVED_ATTRIBUTES.get((cls, name))
    if new is None:
        raise AttributeError(f"{cls!r} object has no attribute {name!r}")
    module, func = new
    _warn(f"{cls}.{name}", f"{module}.{func}({cls.lower()})")
    return getattr(importlib.import_module(module), func)(obj)


class _Shim(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finder and loader of the old module paths: thin modules forwarding to the new ones."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname not in MOVED_MODULES:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: Any) -> ModuleType | None:
        return None  # the default module object

    def exec_module(self, module: ModuleType) -> None:
        new = MOVED_MODULES[module.__name__]
        homes = (new,) if isinstance(new, str) else new
        _warn(module.__name__, " and ".join(homes))
        targets = [importlib.import_module(h) for h in homes]

        def forward(name: str) -> Any:
            for target in targets:
                if hasattr(target, name):
                    return getattr(target, name)
            raise AttributeError(f"module {module.__name__!r} has no attribute {name!r}")

        module.__getattr__ = forward  # type: ignore[method-assign]
        module.__doc__ = f"Deprecated alias of {' and '.join(homes)}."
        module.__dict__["__all__"] = [n for t in targets for n in getattr(t, "__all__", ())]


def install() -> None:
    """Put the shim finder last on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _Shim) for f in sys.meta_path):
        sys.meta_path.append(_Shim())
