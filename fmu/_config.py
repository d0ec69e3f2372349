"""Configuration of the plant's hidden effects (plant spec §10) and its flat-dictionary form.

The flat names double as FMI variable names of the plant FMU, so they are plain identifiers:
``<effect>_on`` switches an effect, ``<effect>_<parameter>`` sets it, ``mount`` selects the
gravity direction and ``seed`` the noise generator.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from tendonkit.errors import OptionError, raise_if
from tendonkit.robot import RobotParameters

__all__ = [
    "MOUNTS",
    "PARAMETER_RANGES",
    "PRESETS",
    "PlantConfig",
    "config_from_dict",
    "config_to_dict",
]

#: Mounting options (spec §1): gravity off (nominal), robot axis up, down, horizontal with the
#: tilt plane vertical, horizontal with the pan plane vertical.
MOUNTS = ("none", "up", "down", "horiz_tilt", "horiz_pan")

# name -> (low, high) valid range of each numeric effect parameter (spec §10).  friction_mu_s
# is checked relative to friction_mu_k separately.
_RANGES: dict[str, tuple[float, float]] = {
    "settle_s": (0.0, 10.0),
    "friction_mu_k": (0.05, 0.3),
    "friction_beta0": (0.02, 0.15),
    "backlash_b": (0.002, 0.02),
    "delay_s": (0.0, 0.15),
    "deadzone_T": (5.0, 40.0),
    "deadzone_w": (1.0, 5.0),
    "forcelag_tau": (0.05, 0.5),
    "forcelag_vmax": (0.001, 0.010),
    "forcelag_kt": (5e3, 1e5),
    "hardening_k3": (0.5, 5.0),
    "softening_s": (0.0, 0.4),
    "softening_qs": (0.2, 0.4),
    "noise_sigma_q": (0.002, 0.015),
    "noise_sigma_p": (1e-4, 1e-3),
    "noise_sigma_T": (0.1, 1.0),
    "noise_quantum_T": (0.0, 1.0),
    "camera_fc": (0.5, 5.0),
}
_MU_S_FACTOR = (1.1, 1.5)
#: Valid range of each numeric effect parameter (plant spec §10), for users of the plant
#: (campaigns draw from them): ``name -> (low, high)``.
PARAMETER_RANGES: dict[str, tuple[float, float]] = dict(_RANGES)


@dataclass(frozen=True)
class PlantConfig:
    """Switches and parameters of the plant's hidden effects; all effects are off by default.

    Every numeric parameter holds its spec default-when-on and is validated against its range
    (spec §10) even while its effect is off.  An invalid configuration raises
    :class:`tendonkit.errors.OptionError` listing every problem.

    Parameters
    ----------
    seed : int
        Seed of the sensor-noise generator (``numpy.random.default_rng``).
    mount : str
        Gravity direction, one of :data:`MOUNTS`; ``"none"`` switches gravity off (effect G).
    settle_s : float
        Seconds of rest at ``P_nom`` simulated by ``reset()`` (useful with gravity).
    friction_on, friction_mu_k, friction_mu_s, friction_beta0
        Effect A, capstan stick–slip at each link crossing: kinetic and static coefficients
        (``mu_s`` in [1.1, 1.5]·``mu_k``) and base wrap per link, rad.
    backlash_on, backlash_b
        Effect B, half-play of each visible joint angle, rad.
    delay_on, delay_s
        Effect D, actuation delay, s (fractional frames allowed).
    deadzone_on, deadzone_T, deadzone_w
        Effect Z, softplus dead zone of the tension entering the robot: threshold and
        smoothing width, N.
    forcelag_on, forcelag_tau, forcelag_vmax, forcelag_kt
        Effect F, force-loop time constant (s), carriage speed limit (m/s) and tendon + drive +
        load-cell stiffness (N/m).
    hardening_on, hardening_k3
        Effect K (hardening), ``τ = −k3 K_i q³``.
    softening_on, softening_s, softening_qs
        Effect K (softening), ``τ = s K_i (q − q_s tanh(q/q_s))``.
    noise_on, noise_sigma_q, noise_sigma_p, noise_sigma_T, noise_quantum_T
        Effect N, white noise on angles (rad), end-effector axes (m) and forces (N); force
        quantisation step (N, 0 = none).
    camera_on, camera_fc
        Effect L, 2nd-order causal Butterworth on visible angles and end effector, cut-off Hz.

    Examples
    --------
    >>> cfg = PlantConfig(friction_on=True, mount="horiz_tilt")
    >>> PlantConfig.from_dict(cfg.to_dict()) == cfg
    True
    """

    seed: int = 0
    mount: str = "none"
    settle_s: float = 0.0
    friction_on: bool = False
    friction_mu_k: float = 0.12
    friction_mu_s: float = 0.16
    friction_beta0: float = 0.05
    backlash_on: bool = False
    backlash_b: float = 0.01
    delay_on: bool = False
    delay_s: float = 0.09
    deadzone_on: bool = False
    deadzone_T: float = 25.0
    deadzone_w: float = 2.0
    forcelag_on: bool = False
    forcelag_tau: float = 0.15
    forcelag_vmax: float = 0.003
    forcelag_kt: float = 2e4
    hardening_on: bool = False
    hardening_k3: float = 2.0
    softening_on: bool = False
    softening_s: float = 0.4
    softening_qs: float = 0.25
    noise_on: bool = False
    noise_sigma_q: float = 0.005
    noise_sigma_p: float = 3e-4
    noise_sigma_T: float = 0.3
    noise_quantum_T: float = 0.0
    camera_on: bool = False
    camera_fc: float = 2.0

    def __post_init__(self) -> None:
        raise_if(self._problems(), OptionError, "Invalid plant configuration:")

    def _problems(self) -> list[str]:
        problems: list[str] = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name.endswith("_on") and not isinstance(value, bool):
                problems.append(f"{f.name} must be true or false, found {value!r}")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            problems.append(f"seed must be an integer >= 0, found {self.seed!r}")
        if self.mount not in MOUNTS:
            problems.append(f"mount must be one of {', '.join(MOUNTS)}; found {self.mount!r}")
        for name, (low, high) in _RANGES.items():
            value = getattr(self, name)
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not ok or not math.isfinite(value) or not (low <= value <= high):
                problems.append(f"{name} must be in [{low:g}, {high:g}], found {value!r}")
        mu_k, mu_s = self.friction_mu_k, self.friction_mu_s
        if isinstance(mu_k, int | float) and isinstance(mu_s, int | float):
            low, high = (mu_k * f for f in _MU_S_FACTOR)
            if not (low * (1 - 1e-9) <= mu_s <= high * (1 + 1e-9)):
                problems.append(
                    f"friction_mu_s must be in [1.1, 1.5]·friction_mu_k = [{low:.4g}, {high:.4g}], "
                    f"found {mu_s!r}"
                )
        return problems

    # --------------------------------------------------------------------------- helpers
    @property
    def effects(self) -> tuple[str, ...]:
        """Names of the effects that are switched on (``"gravity"`` when mounted)."""
        names = [
            f.name[:-3] for f in fields(self) if f.name.endswith("_on") and getattr(self, f.name)
        ]
        if self.mount != "none":
            names.append("gravity")
        return tuple(names)

    def replace(self, **changes: Any) -> PlantConfig:
        """Return a copy with ``changes`` applied (validated).

        Examples
        --------
        >>> PlantConfig().replace(delay_on=True, delay_s=0.03).delay_s
        0.03
        """
        return replace(self, **changes)

    @classmethod
    def preset(cls, name: str) -> PlantConfig:
        """Return a named configuration from :data:`PRESETS`.

        Parameters
        ----------
        name : str
            ``"nominal"`` or ``"paper_like"`` (friction + force lag + 30 ms delay +
            horiz_tilt + 2 Hz camera, spec §10).

        Returns
        -------
        PlantConfig
        """
        if name not in PRESETS:
            raise OptionError(f"Unknown plant preset {name!r}. Presets: {', '.join(PRESETS)}.")
        return cls(**PRESETS[name])

    # ---------------------------------------------------------------- flat dictionary
    def to_dict(self) -> dict[str, bool | int | float | str]:
        """Return the configuration as a flat ``name -> scalar`` dictionary.

        Names are valid FMI variable names; values are bool (``*_on``), int (``seed``),
        str (``mount``) or float.
        """
        return dict(asdict(self))

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PlantConfig:
        """Build a configuration from a flat dictionary; missing names keep their defaults.

        Flags accept bools, 0/1 and the strings ``true``/``false``; ``seed`` accepts integral
        numbers.  Unknown names and bad values are all reported in one
        :class:`~tendonkit.errors.OptionError`.

        Parameters
        ----------
        values : dict
            ``name -> scalar``.

        Returns
        -------
        PlantConfig
        """
        kinds = {f.name: f for f in fields(cls)}
        problems = [f"unknown plant parameter {k!r}" for k in sorted(set(values) - set(kinds))]
        kwargs: dict[str, Any] = {}
        for name, value in values.items():
            if name not in kinds:
                continue
            try:
                kwargs[name] = _coerce(name, value)
            except (TypeError, ValueError):
                problems.append(f"{name} has an invalid value {value!r}")
        raise_if(problems, OptionError, "Invalid plant configuration:")
        return cls(**kwargs)

    @classmethod
    def parameter_names(cls) -> tuple[str, ...]:
        """Names of the flat parameters, in :meth:`to_dict` order."""
        return tuple(f.name for f in fields(cls))


def _coerce(name: str, value: Any) -> bool | int | float | str:
    if name.endswith("_on"):
        if isinstance(value, str):
            low = value.strip().lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise ValueError(value)
        if value in (0, 1):
            return bool(value)
        raise ValueError(value)
    if name == "seed":
        as_float = float(value)
        if not as_float.is_integer():
            raise ValueError(value)
        return int(as_float)
    if name == "mount":
        return str(value)
    return float(value)


#: Named configurations (flat dictionaries) for :meth:`PlantConfig.preset`.
PRESETS: dict[str, dict[str, Any]] = {
    "nominal": {},
    "paper_like": {
        "friction_on": True,
        "forcelag_on": True,
        "delay_on": True,
        "delay_s": 0.03,
        "mount": "horiz_tilt",
        "camera_on": True,
        "camera_fc": 2.0,
    },
}


def config_to_dict(
    config: PlantConfig, robot: RobotParameters | None = None
) -> dict[str, bool | int | float | str]:
    """Flatten a plant configuration (and robot parameters) into ``name -> scalar``.

    The names are the plant FMU's parameter names: effect switches and parameters
    (``friction_on``, ``delay_s``, ``mount``, ``seed`` …, see :class:`PlantConfig`) followed by
    the robot parameters of :meth:`RobotParameters.to_dict` (``rho``, ``P_nom``,
    ``ratio_3`` …).

    Parameters
    ----------
    config : PlantConfig
    robot : RobotParameters, optional
        Defaults to the nominal robot.

    Returns
    -------
    dict

    Examples
    --------
    >>> flat = config_to_dict(PlantConfig(delay_on=True))
    >>> flat["delay_on"], flat["P_nom"]
    (True, 105.0)
    """
    out: dict[str, bool | int | float | str] = dict(config.to_dict())
    out.update((robot or RobotParameters()).to_dict())
    return out


def config_from_dict(values: dict[str, Any]) -> tuple[PlantConfig, RobotParameters]:
    """Inverse of :func:`config_to_dict`: split a flat dictionary into config and robot.

    Missing names keep their defaults; unknown names and invalid values are reported together
    in one :class:`~tendonkit.errors.OptionError`.

    Parameters
    ----------
    values : dict
        ``name -> scalar``.

    Returns
    -------
    (PlantConfig, RobotParameters)
    """
    config_names = set(PlantConfig.parameter_names())
    robot_names = set(RobotParameters.parameter_names())
    unknown = sorted(set(values) - config_names - robot_names)
    problems = [f"unknown plant parameter {name!r}" for name in unknown]
    config: PlantConfig | None = None
    robot: RobotParameters | None = None
    try:
        config = PlantConfig.from_dict({k: v for k, v in values.items() if k in config_names})
    except OptionError as err:
        problems.extend(err.problems or [str(err)])
    try:
        robot = RobotParameters.from_dict({k: v for k, v in values.items() if k in robot_names})
    except OptionError as err:
        problems.extend(err.problems or [str(err)])
    except (TypeError, ValueError) as err:
        problems.append(f"robot parameters: {err}")
    if problems or config is None or robot is None:
        raise OptionError("Invalid plant parameters:", problems)
    return config, robot
